"""The 3D target sets (ngpm_compiler/datasets/sets3d.py): blobs3d, extruded, revolved."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ngpm_runtime.program import Program
from ngpm_runtime.volume.load import load_volume_dataset
from ngpm_runtime.volume.start import label_largest
from ngpm_runtime.volume.target import VolumeTarget
from PIL import Image, ImageDraw

from ngpm_compiler.cli import main
from ngpm_compiler.datasets.build import DATASETS, build_dataset
from ngpm_compiler.datasets.common import DatasetError, DatasetWarning
from ngpm_compiler.datasets.sets3d import blob3d, mirrored3d

R = 16  # small grids keep the builds fast


def built(directory) -> list[VolumeTarget]:
    return load_volume_dataset(directory)


def at_start(t: VolumeTarget) -> bool:
    """Whether the voxel just above the start is filled."""
    return bool(t.occupancy[tuple(t.world_to_index(t.start + [0, 1e-9, 0]))])


def test_the_3d_sets_are_registered():
    assert {n for n, s in DATASETS.items() if s.dim == 3} == {"blobs3d", "extruded", "revolved"}


@pytest.mark.parametrize("name", ["blobs3d", "extruded", "revolved"])
def test_builds_are_seeded_and_reproducible(tmp_path, name):
    files = build_dataset(name, tmp_path / "a", count=3, seed=4, resolution=R)
    assert [f.name for f in files] == [f"{name}_{i:04d}.npz" for i in range(3)]
    assert all(f.with_suffix(".png").is_file() for f in files)
    assert Image.open(files[0].with_suffix(".png")).size == (160, 160)
    build_dataset(name, tmp_path / "b", count=3, seed=4, resolution=R)
    build_dataset(name, tmp_path / "c", count=3, seed=5, resolution=R)
    a, b, c = (built(tmp_path / d) for d in "abc")
    for f in files:  # the same bytes, pictures too
        for suffix in (".npz", ".png"):
            again = tmp_path / "b" / f.with_suffix(suffix).name
            assert again.read_bytes() == f.with_suffix(suffix).read_bytes()
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x.occupancy, y.occupancy) and np.array_equal(x.start, y.start)
    assert any(not np.array_equal(x.occupancy, z.occupancy) for x, z in zip(a, c, strict=True))
    for t in a:
        # in the unit cube, the shape on its floor and as tall, wide or deep as the cube
        assert t.resolution == R and t.lo.tolist() == [0, 0, 0] and t.voxel == 1 / R
        occ = t.occupancy
        assert occ[:, 0, :].any()
        spans = [
            np.ptp(np.nonzero(occ.any(axis=tuple(k for k in range(3) if k != a)))[0]) + 1
            for a in range(3)
        ]
        assert max(spans) >= R - 1
        assert 0.005 < occ.mean() < 0.9
    meta = json.loads((tmp_path / "a" / "index.json").read_text())
    assert meta["complete"] and meta["resolution"] == R and "size" not in meta


def test_blobs_start_at_the_bottom_of_their_largest_part():
    for i in range(4):
        t = blob3d(np.random.default_rng([0, 31, i]), R)
        assert at_start(t)
        part = label_largest(t.occupancy)  # a small piece apart does not count
        assert t.start[1] == t.lo[1] + t.voxel * np.nonzero(part.any(axis=(0, 2)))[0][0]


def test_extruded_targets_start_where_the_2d_target_does(tmp_path):
    build_dataset("extruded", tmp_path, count=6, seed=1, resolution=R)
    sources = json.loads((tmp_path / "index.json").read_text())["sources"]
    assert [s.split()[1] for s in sources[:3]] == ["scribble", "varied", "glyph"]
    for t in built(tmp_path):
        assert t.start[2] == pytest.approx(0.5)  # halfway through the slab, in the middle
        depth = np.nonzero(t.occupancy.any(axis=(0, 1)))[0]
        assert np.ptp(depth) + 1 < R  # a slab: thinner than the shape


def test_revolved_targets_are_round(tmp_path):
    build_dataset("revolved", tmp_path, count=4, seed=0, resolution=R)
    for t in built(tmp_path):
        occ = t.occupancy
        assert np.mean(occ != occ.transpose(2, 1, 0)) < 0.01
        assert at_start(t)


def test_revolved_from_a_folder_skips_unusable_pictures(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    img = Image.new("L", (80, 80), 255)
    ImageDraw.Draw(img).polygon([(40, 10), (60, 70), (20, 70)], fill=0)  # a cone's outline
    img.save(src / "cone.png")
    Image.new("L", (80, 80), 255).save(src / "blank.png")
    with pytest.warns(DatasetWarning, match="blank"):
        files = build_dataset("revolved", tmp_path / "out", resolution=R, source_dir=src)
    assert len(files) == 1
    (cone,) = built(tmp_path / "out")
    areas = cone.occupancy.sum(axis=(0, 2))
    filled = areas[areas > 0]
    assert filled[0] > filled[-1]  # wide at the bottom, narrow at the top
    assert json.loads((tmp_path / "out" / "index.json").read_text())["sources"] == [
        "revolved cone.png"
    ]


def test_mirror_resume_and_other_settings(tmp_path):
    files = build_dataset("blobs3d", tmp_path, count=2, resolution=R, mirror=True)
    assert [f.name for f in files] == [
        "blobs3d_0000.npz",
        "blobs3d_0000_m.npz",
        "blobs3d_0001.npz",
        "blobs3d_0001_m.npz",
    ]
    t, m = built(tmp_path)[:2]
    assert np.array_equal(m.occupancy, t.occupancy[::-1])
    assert m.start[0] == pytest.approx(1.0 - t.start[0])
    assert mirrored3d(m).name.endswith("_m_m")
    stamp = files[0].stat().st_mtime_ns
    build_dataset("blobs3d", tmp_path, count=2, resolution=R, mirror=True)
    assert files[0].stat().st_mtime_ns == stamp  # kept: the build resumes
    with pytest.raises(DatasetError, match="other settings"):
        build_dataset("blobs3d", tmp_path, count=2, resolution=24, mirror=True)
    with pytest.raises(DatasetError, match="resolution must be"):
        build_dataset("blobs3d", tmp_path / "x", resolution=4)


def test_cli_builds_a_3d_set_placed_by_a_3d_grammar(tmp_path, capsys):
    code = main(
        ["targets", "build", "blobs3d", "-o", str(tmp_path), "--count", "2", "--resolution", "12"]
    )
    assert code == 0
    assert "blobs3d: 2 targets" in capsys.readouterr().out
    assert main(["targets", "show", str(tmp_path), "-o", str(tmp_path / "sheet.png")]) == 0
    assert "2 of 2 3D targets" in capsys.readouterr().out
    assert Image.open(tmp_path / "sheet.png").size == (2 * 68 + 4, 68 + 12 + 4)
    box = (-600.0, 600.0, -20.0, 1150.0, -600.0, 600.0)
    tree = Program(name="t", sites=[], axiom=lambda ctx: [], productions={}, dim=3, box=box)
    placed = load_volume_dataset(tmp_path, tree)
    assert all(t.resolution == 12 and t.lo.tolist() == [-600, -20, -600] for t in placed)
    assert all(at_start(t) for t in placed)
