"""load_volume_target (ngpm_runtime.volume.load) and start points (volume/start.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.image.targets import load_target
from ngpm_runtime.program import Program
from ngpm_runtime.volume.load import (
    UNIT_BOX,
    load_volume_dataset,
    load_volume_target,
    place,
    volume_from_lattice,
)
from ngpm_runtime.volume.start import (
    auto_start,
    label_largest,
    read_sidecar3d,
    write_sidecar3d,
)
from ngpm_runtime.volume.target import VolumeError
from PIL import Image, ImageDraw

trimesh = pytest.importorskip("trimesh")

BOX = (-600.0, 600.0, -20.0, 1150.0, -600.0, 600.0)  # tree3d.lsys's viewport


def program(dim: int = 3) -> Program:
    box = BOX if dim == 3 else None
    return Program(name="t", sites=[], axiom=lambda ctx: [], productions={}, dim=dim, box=box)


def sphere_file(tmp_path: Path, name: str = "ball.stl") -> Path:
    trimesh.creation.icosphere(subdivisions=4, radius=2.0).export(tmp_path / name)
    return tmp_path / name


def picture(tmp_path: Path, name: str = "bar.png") -> Path:
    """A dark bar standing on a wider foot, on white."""
    img = Image.new("L", (100, 100), 255)
    draw = ImageDraw.Draw(img)
    draw.rectangle((44, 20, 56, 90), fill=0)
    draw.rectangle((30, 82, 70, 90), fill=0)
    img.save(tmp_path / name)
    return tmp_path / name


def test_a_mesh_fills_the_grammar_box_from_its_floor(tmp_path):
    t = load_volume_target(sphere_file(tmp_path), program())
    assert t.name == "ball" and t.resolution == 32
    assert t.lo.tolist() == [-600.0, -20.0, -600.0] and t.voxel == 1200 / 32
    # the ball is scaled to the box's height (1170), its floor on the box's floor
    radius = 1170 / 2
    expected = 4 / 3 * np.pi * radius**3 / 1200**3
    assert t.occupancy.mean() == pytest.approx(expected, rel=0.03)
    assert t.occupancy[:, 0, :].any() and not t.occupancy[:, 31, :].any()
    assert np.array_equal(t.occupancy, t.occupancy[::-1, :, ::-1]) or (
        np.mean(t.occupancy != t.occupancy[::-1, :, ::-1]) < 0.01
    )
    # automatic start: the middle of the bottom, on the box floor
    assert t.start[1] == -20.0
    assert abs(t.start[0]) <= t.voxel and abs(t.start[2]) <= t.voxel
    assert t.occupancy[tuple(t.world_to_index(t.start + [0, 1e-6, 0]))]


def test_a_mesh_sidecar_sets_the_start(tmp_path):
    path = sphere_file(tmp_path, "ball.obj")
    write_sidecar3d(tmp_path / "ball.txt", np.array([0.5, 1.0, 0.5]))
    t = load_volume_target(path, program(), resolution=16)
    assert t.resolution == 16
    assert t.start == pytest.approx([0.0, 1150.0, 0.0], abs=1e-6)  # the ball's top
    (tmp_path / "ball.txt").write_text("0.5 0.5\n0 1\n")
    with pytest.raises(VolumeError, match=r"bad sidecar .*ball\.txt: expected one line 'x y z'"):
        load_volume_target(path, program())
    (tmp_path / "ball.txt").write_text("0.5 1.5 0.5\n")
    with pytest.raises(VolumeError, match="each of x y z must be from 0 to 1"):
        load_volume_target(path, program())


def test_sidecar_round_trip(tmp_path):
    write_sidecar3d(tmp_path / "s.txt", np.array([0.25, 0.0, 1.0]))
    assert read_sidecar3d(tmp_path / "s.txt").tolist() == [0.25, 0.0, 1.0]
    (tmp_path / "c.txt").write_text("0.1, 0.2, 0.3\n")
    assert read_sidecar3d(tmp_path / "c.txt").tolist() == [0.1, 0.2, 0.3]


def test_extruded_picture(tmp_path):
    t = load_volume_target(picture(tmp_path), program(), extrude=0.25)
    occ = t.occupancy
    assert t.name == "bar"
    assert occ[:, 0, :].any()
    zs = np.nonzero(occ.any(axis=(0, 1)))[0]
    xs = np.nonzero(occ.any(axis=(1, 2)))[0]
    # the picture is read at 64 x 64 px (twice the grid), where the shape is 45 px tall
    # and 27 wide and the slab a quarter of the side (16 px) deep: all three scaled alike,
    # the height to the box's (31.2 voxels); voxels at least half inside are filled
    mask = load_target(tmp_path / "bar.png", size=64).mask
    rows, cols = np.nonzero(mask)
    assert (np.ptp(rows) + 1, np.ptp(cols) + 1) == (45, 27)
    scale = 1170 / t.voxel / 45
    assert len(zs) == pytest.approx(16 * scale, abs=1.5)
    assert len(xs) == pytest.approx(27 * scale, abs=1.5)
    # every layer in depth is the same picture (the first and last, partly inside the
    # slab, keep only the voxels wholly inside the picture's shape)
    assert all(np.array_equal(occ[:, :, zs[1]], occ[:, :, z]) for z in zs[1:-1])
    assert not np.any(occ[:, :, zs[0]] & ~occ[:, :, zs[1]])
    # the automatic start: the middle of the foot's bottom
    assert t.start[1] == -20.0 and abs(t.start[0]) <= t.voxel and abs(t.start[2]) <= t.voxel


def test_a_picture_sidecar_gives_the_start_in_the_picture_plane(tmp_path):
    path = picture(tmp_path)
    (tmp_path / "bar.txt").write_text("0.5 0.2\n0 -1\n")  # the top of the bar
    t = load_volume_target(path, program(), extrude=0.25)
    # the picture is read at 64 x 64 px, so the bar's edges move by up to a pixel
    assert t.start[2] == pytest.approx(0.0, abs=1e-6)  # halfway through the slab
    assert abs(t.start[0]) < t.voxel / 2
    assert t.start[1] == pytest.approx(1150.0, abs=t.voxel / 2)


def test_revolved_picture_is_round(tmp_path):
    t = load_volume_target(picture(tmp_path), program(), revolve=True)
    occ = t.occupancy
    assert np.mean(occ != occ.transpose(2, 1, 0)) < 0.005  # x and z alike
    assert np.mean(occ != occ[::-1, :, :]) < 0.005
    low = np.nonzero(occ.any(axis=(0, 2)))[0][0]
    foot = occ[:, low, :].sum()
    bar = occ[:, low + 10, :].sum()
    assert foot > 5 * bar > 0  # a wide disc under a thin column


@pytest.mark.parametrize(
    "name, kwargs, message",
    [
        ("bar.png", {}, r"bar\.png is a picture: make it 3D with --extrude DEPTH"),
        ("bar.png", {"extrude": 0.2, "revolve": True}, "choose --extrude or --revolve"),
        ("bar.png", {"extrude": 0.0}, "--extrude must be a depth above 0"),
        ("ball.stl", {"revolve": True}, "--extrude and --revolve make pictures 3D"),
        ("ball.xyz", {}, "a 3D target is a mesh or a .npz"),
        ("ball.stl", {"resolution": 3}, "resolution must be an integer from 4 to 256"),
    ],
)
def test_bad_requests_are_one_line_errors(tmp_path, name, kwargs, message):
    picture(tmp_path)
    sphere_file(tmp_path)
    (tmp_path / "ball.xyz").write_text("1 2 3\n")
    with pytest.raises(VolumeError, match=message) as err:
        load_volume_target(tmp_path / name, program(), **kwargs)
    assert "\n" not in str(err.value)


def test_bad_meshes_name_the_file(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    trimesh.Trimesh(mesh.vertices, mesh.faces[3:]).export(tmp_path / "open.obj")
    with pytest.raises(VolumeError, match=r"mesh .*open\.obj is not watertight"):
        load_volume_target(tmp_path / "open.obj", program())
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\n")
    with pytest.raises(VolumeError, match=r"points\.obj holds no triangles"):
        load_volume_target(tmp_path / "points.obj", program())
    (tmp_path / "junk.glb").write_bytes(b"\0" * 40)
    with pytest.raises(VolumeError, match=r"junk\.glb: not a binary glTF"):
        load_volume_target(tmp_path / "junk.glb", program())
    with pytest.raises(NgpmError, match="does not exist"):
        load_volume_target(tmp_path / "none.ply", program())


def test_a_2d_grammar_is_refused(tmp_path):
    with pytest.raises(VolumeError, match="is a 2D grammar: a 3D target needs a 3D grammar"):
        load_volume_target(sphere_file(tmp_path), program(dim=2))


def test_npz_targets_are_placed_in_the_grammar_grid(tmp_path):
    t = load_volume_target(sphere_file(tmp_path), program())
    t.to_npz(tmp_path / "same.npz")
    same = load_volume_target(tmp_path / "same.npz", program())
    assert np.array_equal(same.occupancy, t.occupancy) and np.array_equal(same.start, t.start)
    lat = np.zeros((10, 20, 10), dtype=bool)
    lat[3:7, :, 3:7] = True  # a post 4 x 20 x 4
    unit = volume_from_lattice(lat, UNIT_BOX, 32, "post")
    assert unit.lo.tolist() == [0, 0, 0] and unit.voxel == 1 / 32
    # scaled to the cube's height: 6.4 voxels wide, of which 6 are more than half inside
    assert unit.occupancy.sum() == 6 * 32 * 6
    unit.to_npz(tmp_path / "post.npz")
    moved = load_volume_target(tmp_path / "post.npz", program())
    assert moved.lo.tolist() == [-600.0, -20.0, -600.0]
    assert moved.occupancy.sum() == pytest.approx(6 * 31 * 6, rel=0.1)  # box 1170 / 1200 high
    assert moved.start[1] == -20.0
    assert place(moved, BOX) is moved


def test_load_volume_dataset(tmp_path):
    with pytest.raises(VolumeError, match="no index.json"):
        load_volume_dataset(tmp_path)
    lat = np.ones((2, 4, 2), dtype=bool)
    volume_from_lattice(lat, UNIT_BOX, 8, "a").to_npz(tmp_path / "a.npz")
    (tmp_path / "index.json").write_text('{"files": ["a.npz"], "complete": true}')
    (one,) = load_volume_dataset(tmp_path)
    assert one.resolution == 8
    (placed,) = load_volume_dataset(tmp_path, program(), 16)
    assert placed.resolution == 16 and placed.lo[1] == -20.0
    (tmp_path / "index.json").write_text('{"files": ["a.npz"], "complete": false}')
    with pytest.raises(VolumeError, match="incomplete"):
        load_volume_dataset(tmp_path)
    # a set of pictures (a 2D dataset's index) is named as such, not read as .npz files
    (tmp_path / "index.json").write_text('{"files": ["a.npz", "b.png"], "complete": true}')
    with pytest.raises(VolumeError, match="is a set of pictures, not of 3D targets"):
        load_volume_dataset(tmp_path)


def test_auto_start_takes_the_largest_part_bottom_middle():
    occ = np.zeros((9, 9, 9), dtype=bool)
    occ[2:7, 3:8, 2:7] = True  # a block from layer 3 up
    occ[0, 0, 0] = occ[0, 1, 0] = True  # a speck lower down, apart
    assert label_largest(occ).sum() == 125
    assert auto_start(occ).tolist() == [4.5, 3.0, 4.5]
    ell = np.zeros((6, 6, 6), dtype=bool)
    ell[0:5, 0, 1] = True  # a foot along x
    ell[4, 0:6, 1] = True  # a post at its end
    # the part's centre seen from above is x = 3.4 (of 10 voxels, 6 at x = 4): the foot's
    # voxel under it is x = 3
    assert auto_start(ell).tolist() == [3.5, 0.0, 1.5]
    with pytest.raises(VolumeError, match="no filled voxel"):
        auto_start(np.zeros((3, 3, 3), dtype=bool))


def test_parts_touching_at_an_edge_or_corner_are_one():
    occ = np.zeros((6, 6, 6), dtype=bool)
    occ[0, 0, 0] = occ[1, 1, 1] = occ[2, 2, 1] = True  # a diagonal chain: 3 voxels
    occ[4:6, 4:6, 4] = True  # 4 voxels apart
    assert label_largest(occ).sum() == 4
    occ[3, 3, 2] = occ[4, 4, 3] = True  # corners join the chain to the square
    assert label_largest(occ).sum() == 9
