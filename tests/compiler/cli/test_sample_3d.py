"""`ngpmc sample` of the shipped 3D grammars (meshes read back by trimesh and pygltflib,
pictures), and the 2D outputs left as they were."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from repo_paths import REPO

from ngpm_compiler.cli import grammar as grammar_cli
from ngpm_compiler.cli import main

trimesh = pytest.importorskip("trimesh")
pygltflib = pytest.importorskip("pygltflib")

VINES = REPO / "grammars" / "vines.lsys"
PLANT = REPO / "grammars" / "plant3d.lsys"  # ABOP Figure 1.26: the smallest shipped 3D grammar
TREE = REPO / "grammars" / "stochastic_tree3d.lsys"  # has random sites


def plant_mesh(seed: int = 0):
    """The plant's forward sample and its mesh, through the Python API."""
    from ngpm_runtime import mesh_from_primitives
    from ngpm_runtime.inference.smc import forward

    prims = list(forward(grammar_cli.load(str(PLANT)).program(), seed=seed).primitives)
    return prims, mesh_from_primitives(prims)


def drawn(path: Path) -> np.ndarray:
    """True where a picture is not the white background."""
    with Image.open(path) as pic:
        rgb = np.asarray(pic.convert("RGB"), dtype=np.int16)
    return np.abs(rgb - 255).max(axis=2) > 24


@pytest.mark.parametrize("suffix", [".glb", ".obj", ".ply"])
def test_sample_writes_a_mesh_of_a_3d_grammar(
    tmp_path: Path, suffix: str, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / f"plant{suffix}"
    assert main(["sample", str(PLANT), "-o", str(out)]) == 0
    prims, mesh = plant_mesh()
    loaded = trimesh.load(out, process=False)
    geoms = list(loaded.geometry.values()) if hasattr(loaded, "geometry") else [loaded]
    assert sum(len(g.faces) for g in geoms) == len(mesh.faces) > 1000
    assert np.allclose(loaded.bounds, mesh.bounds, atol=1e-4)  # Y up, the grammar's units
    assert mesh.bounds[1, 1] > 30  # the plant grows up, tens of units tall
    line = capsys.readouterr().out
    assert f"{len(prims)} primitives" in line and f"{len(mesh.faces)} triangles" in line
    assert str(out) in line and "status done" in line


def test_glb_of_a_3d_grammar_reads_in_pygltflib_with_its_materials(tmp_path: Path) -> None:
    from ngpm_runtime.geometry.mesh_base import PALETTE

    out = tmp_path / "plant.glb"
    assert main(["sample", str(PLANT), "-o", str(out)]) == 0
    _, mesh = plant_mesh()
    gltf = pygltflib.GLTF2().load(str(out))
    assert gltf.asset.version == "2.0"
    used = sorted(set(mesh.face_material.tolist()))
    assert [m.name for m in gltf.materials] == [PALETTE[m].name for m in used]
    assert {"bark", "leaf"} <= {m.name for m in gltf.materials}  # stems and leaves
    prims = gltf.meshes[0].primitives
    assert sum(gltf.accessors[p.indices].count for p in prims) == 3 * len(mesh.faces)


def test_png_gif_and_view_of_a_3d_grammar(tmp_path: Path) -> None:
    """The picture from +Z shows the plant where its mesh projects: the drawn pixels span the
    mesh's X and Y extents, fitted into the picture with its margin."""
    from ngpm_runtime.image.render3d import MARGIN

    size = 160
    args = [
        "sample",
        str(PLANT),
        "-o",
        str(tmp_path / "t.glb"),
        "--png",
        str(tmp_path / "p.png"),
        "--gif",
        str(tmp_path / "t.gif"),
        "--view",
        "0,0",
        "--size",
        str(size),
    ]
    assert main(args) == 0
    assert (tmp_path / "t.glb").stat().st_size > 10_000
    with Image.open(tmp_path / "t.gif") as pic:
        assert pic.size == (size // 2, size // 2) and pic.n_frames == 24
    mask = drawn(tmp_path / "p.png")
    assert mask.shape == (size, size) and 0.02 < mask.mean() < 0.5
    _, mesh = plant_mesh()
    lo, hi = mesh.bounds
    scale = size * (1 - 2 * MARGIN) / max(hi[:2] - lo[:2])
    mid = (lo[:2] + hi[:2]) / 2
    rows, cols = np.nonzero(mask)
    expect = [
        size / 2 + (lo[0] - mid[0]) * scale,
        size / 2 + (hi[0] - mid[0]) * scale,
        size / 2 - (hi[1] - mid[1]) * scale,
        size / 2 - (lo[1] - mid[1]) * scale,
    ]
    got = [cols.min(), cols.max() + 1, rows.min(), rows.max() + 1]
    assert np.allclose(got, expect, atol=3), (got, expect)
    stem = round(size / 2 + (0 - mid[0]) * scale)  # the stem rises from the origin
    bottom = round(expect[3])
    foot = mask[bottom - 4 : bottom]  # the picture's lowest rows: the stem alone
    assert foot[:, stem - 2 : stem + 2].any()
    assert not foot[:, : stem - 4].any() and not foot[:, stem + 4 :].any()


def test_png_alone_of_a_3d_grammar_is_a_shaded_picture(tmp_path: Path) -> None:
    assert main(["sample", str(PLANT), "-o", str(tmp_path / "o.png"), "--size", "48"]) == 0
    with Image.open(tmp_path / "o.png") as pic:
        assert pic.size == (48, 48)
        colours = np.asarray(pic.convert("RGB")).reshape(-1, 3)
    assert drawn(tmp_path / "o.png").mean() > 0.02
    assert len(np.unique(colours, axis=0)) > 20  # shaded, not a flat silhouette


def test_a_compiled_3d_sampler_samples_as_its_grammar(tmp_path: Path) -> None:
    assert main(["compile", str(PLANT), "-o", str(tmp_path)]) == 0
    assert (
        main(["sample", str(tmp_path / "plant3d_sampler.py"), "-o", str(tmp_path / "a.glb")]) == 0
    )
    assert main(["sample", str(PLANT), "-o", str(tmp_path / "b.glb")]) == 0
    assert (tmp_path / "a.glb").read_bytes() == (tmp_path / "b.glb").read_bytes()


def test_seeded_3d_samples_are_reproducible(tmp_path: Path) -> None:
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        assert (
            main(["sample", str(TREE), "--seed", str(seed), "-o", str(tmp_path / f"{name}.ply")])
            == 0
        )
    a, b, c = ((tmp_path / f"{n}.ply").read_bytes() for n in "abc")
    assert a == b and a != c


def test_svg_of_a_3d_grammar_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sample", str(PLANT), "-o", str(tmp_path / "t.svg")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "SVG output is for 2D grammars" in err
    assert "plant3d.lsys is 3D" in err and "--view 0,0" in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "extra",
    [
        ["-o", "t.glb"],
        ["-o", "t.ply"],
        ["-o", "t.png", "--gif", "t.gif"],
        ["-o", "t.png", "--view", "0,0"],
    ],
)
def test_mesh_options_of_a_2d_grammar_are_one_line_errors(
    tmp_path: Path, extra: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    extra = [str(tmp_path / x) if x.startswith("t.") else x for x in extra]
    assert main(["sample", str(VINES), *extra]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "for 3D grammars" in err and "is 2D" in err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("bad", ["45", "a,b", "0,91", "nan,0"])
def test_view_is_checked(bad: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["sample", str(VINES), "-o", "x.png", "--view", bad])
    assert exit_.value.code == 2 and "--view" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", [".png", ".svg"])
def test_2d_pictures_are_those_of_save_render(tmp_path: Path, suffix: str) -> None:
    from ngpm_runtime.image.render import save_render
    from ngpm_runtime.inference.smc import forward

    out = tmp_path / f"cli{suffix}"
    assert main(["sample", str(VINES), "--seed", "4", "-o", str(out), "--size", "96"]) == 0
    program = grammar_cli.load(str(VINES)).program()
    ref = save_render(
        list(forward(program, seed=4).primitives),
        tmp_path / f"ref{suffix}",
        viewport=program.viewport,
        size=96,
    )
    assert out.read_bytes() == ref.read_bytes()
