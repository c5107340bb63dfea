"""Ray-parity voxelization of meshes, the mesh readers, extrude and revolve
(ngpm_runtime.volume.voxelize, geometry/mesh_read.py)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from ngpm_runtime.geometry.mesh_base import MeshError
from ngpm_runtime.geometry.mesh_read import read_mesh
from ngpm_runtime.volume.target import VolumeError
from ngpm_runtime.volume.voxelize import (
    check_closed,
    extrude,
    open_edges,
    revolve,
    sample_lattice,
    voxelize_mesh,
    weld,
)

trimesh = pytest.importorskip("trimesh")

R = 32
ORIGIN = np.array([-1.0, -1.0, -1.0])  # a grid over [-1, 1]^3
STEP = 2.0 / R


def fraction(mesh) -> float:
    return float(voxelize_mesh(mesh.vertices, mesh.faces, ORIGIN, STEP, R).mean())


def test_cube_fills_its_volume_exactly():
    # faces on voxel boundaries; the diagonals of its faces pass through voxel centres
    # seen from above, so rays must be jittered off them
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    occ = voxelize_mesh(cube.vertices, cube.faces, ORIGIN, STEP, R)
    assert occ.sum() == 16**3
    assert occ[8:24, 8:24, 8:24].all()


def test_sphere_and_torus_fill_close_to_their_volume():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.9)
    assert fraction(sphere) == pytest.approx(sphere.volume / 8.0, rel=0.02)
    torus = trimesh.creation.torus(major_radius=0.6, minor_radius=0.25)
    assert fraction(torus) == pytest.approx(torus.volume / 8.0, rel=0.05)


def test_a_box_holds_exactly_the_voxel_centres_inside_it():
    lo, hi = np.array([-0.255, -0.855, -0.14]), np.array([0.475, 0.455, 0.28])
    box = trimesh.creation.box(extents=hi - lo)
    box.apply_translation((lo + hi) / 2)
    centres = ORIGIN[0] + (np.arange(R) + 0.5) * STEP  # the same along each axis
    inside = [(centres > lo[a]) & (centres < hi[a]) for a in range(3)]
    expected = inside[0][:, None, None] & inside[1][None, :, None] & inside[2][None, None, :]
    occ = voxelize_mesh(box.vertices, box.faces, ORIGIN, STEP, R)
    assert np.array_equal(occ, expected)


def test_a_mesh_cut_by_the_grid_still_fills_the_part_inside():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.9)
    full = voxelize_mesh(sphere.vertices, sphere.faces, ORIGIN, STEP, R)
    # the grid moved up by half its height: crossings below it still count
    upper = voxelize_mesh(sphere.vertices, sphere.faces, ORIGIN + [0, 1.0, 0], STEP, R)
    assert np.array_equal(upper[:, : R // 2, :], full[:, R // 2 :, :])
    assert not upper[:, R // 2 :, :].any()


def test_open_and_empty_meshes_are_refused_naming_them():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    with pytest.raises(VolumeError, match=r"^ball\.stl is not watertight: \d+ edge"):
        check_closed(sphere.vertices, sphere.faces[1:], "ball.stl")
    with pytest.raises(VolumeError, match="holds no triangles"):
        check_closed(np.zeros((0, 3)), np.zeros((0, 3), np.int64), "empty.obj")
    flat = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0]], dtype=float)
    with pytest.raises(VolumeError, match="no triangles with an area"):
        check_closed(flat, np.array([[0, 1, 2]]), "flat.obj")


def test_weld_joins_a_triangle_soup():
    cube = trimesh.creation.box()
    soup = cube.vertices[cube.faces].reshape(-1, 3)
    faces = np.arange(len(soup)).reshape(-1, 3)
    assert open_edges(faces) == len(faces) * 3  # every edge alone before welding
    v, f = weld(soup, faces)
    assert len(v) == 8 and open_edges(f) == 0


def test_extrude_and_revolve_a_drawn_mask():
    mask = np.zeros((10, 8), dtype=bool)
    mask[2:9, 3:5] = True  # a bar 7 rows tall, 2 columns wide
    mask[8, 1:7] = True  # on a foot at the bottom
    slab = extrude(mask, 3)
    assert slab.shape == (8, 10, 3)
    assert slab.sum() == 3 * mask.sum()
    assert slab[3, 1, 0] and slab[1, 1, 2] and not slab[1, 2, 1]  # the foot is low (y up)
    with pytest.raises(VolumeError, match="depth"):
        extrude(mask, 0)
    solid = revolve(mask)
    assert solid.shape == (6, 10, 6)  # the shape's width: columns 1..6
    # by layer, from the bottom: the foot a disc (cells nearer than 3 to the axis), the bar
    # (columns 3 and 4, the axis at 4) a column of 2 x 2 cells
    assert solid.sum(axis=(0, 2)).tolist() == [0, 32, 4, 4, 4, 4, 4, 4, 0, 0]
    assert np.array_equal(solid, solid[::-1, :, :]) and np.array_equal(solid, solid[:, :, ::-1])
    with pytest.raises(VolumeError, match="empty"):
        revolve(np.zeros((4, 4), dtype=bool))


def test_sample_lattice_scales_by_area():
    lat = np.zeros((4, 4, 4), dtype=bool)
    lat[:2] = True
    assert sample_lattice(lat, np.zeros(3), 1.0, 4).sum() == 32  # same cells
    fine = sample_lattice(lat, np.zeros(3), 0.5, 8)  # twice as fine
    assert fine[:4].all() and not fine[4:].any()
    coarse = sample_lattice(lat, np.zeros(3), 2.0, 2)
    assert coarse[0].all() and not coarse[1].any()


# --- mesh files ---------------------------------------------------------------------------


def _same_geometry(path: Path, mesh) -> None:
    v, f = read_mesh(path)
    wv, wf = weld(v, f)
    assert open_edges(wf) == 0
    assert len(wf) == len(mesh.faces)
    assert np.allclose(np.sort(wv, axis=0), np.sort(mesh.vertices, axis=0), atol=1e-5)
    occ = voxelize_mesh(v, f, ORIGIN, STEP, R)
    assert occ.mean() == pytest.approx(mesh.volume / 8.0, rel=0.03)


@pytest.mark.parametrize(
    "name, kind",
    [
        ("m.obj", {}),
        ("m.stl", {}),
        ("ascii.stl", {"file_type": "stl_ascii"}),
        ("m.ply", {}),
        ("ascii.ply", {"encoding": "ascii"}),
        ("m.glb", {}),
    ],
)
def test_each_mesh_format_reads_back(tmp_path, name, kind):
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.8)
    mesh.export(tmp_path / name, **kind)
    _same_geometry(tmp_path / name, mesh)


def test_glb_node_transforms_are_applied(tmp_path):
    box = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    scene = trimesh.Scene()
    scene.add_geometry(box, transform=trimesh.transformations.translation_matrix((0.3, 0, 0)))
    scene.export(tmp_path / "moved.glb")
    v, _ = read_mesh(tmp_path / "moved.glb")
    assert np.allclose(v.min(axis=0), [0.05, -0.25, -0.25])


def test_obj_polygons_and_negative_indices(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1/1 2/2 3/3 4/4\nf -4 -2 -1\n"
    (tmp_path / "q.obj").write_text(text)
    _, f = read_mesh(tmp_path / "q.obj")
    assert f.tolist() == [[0, 1, 2], [0, 2, 3], [0, 2, 3]]


def test_binary_ply_big_endian_and_mixed_polygons(tmp_path):
    head = (
        "ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty double x\n"
        "property double y\nproperty double z\nelement face 2\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
    body = struct.pack(">12d", 0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0)
    body += struct.pack(">B4i", 4, 0, 1, 2, 3) + struct.pack(">B3i", 3, 0, 2, 3)
    (tmp_path / "b.ply").write_bytes(head.encode() + body)
    v, f = read_mesh(tmp_path / "b.ply")
    assert v[2].tolist() == [1, 1, 0]
    assert f.tolist() == [[0, 1, 2], [0, 2, 3], [0, 2, 3]]


@pytest.mark.parametrize(
    "name, data, message",
    [
        ("x.stl", b"not a mesh at all", "neither ASCII STL nor binary STL"),
        ("x.ply", b"ply\nformat weird 1.0\nend_header\n", "PLY format 'weird'"),
        ("x.glb", b"glTF\x01\x00\x00\x00\x0c\x00\x00\x00", "not a binary glTF 2.0"),
        ("x.obj", b"v 0 0 0\nf 1 2 3\n", "a face refers to a vertex that does not exist"),
        ("x.obj", b"v 0 0\n", r"x\.obj:1: a vertex needs three coordinates"),
        ("x.obj", b"v a b c\n", "cannot read mesh"),
        ("x.off", b"OFF\n", "unknown mesh format '.off'"),
    ],
)
def test_bad_mesh_files_are_one_line_errors(tmp_path, name, data, message):
    (tmp_path / name).write_bytes(data)
    with pytest.raises(MeshError, match=message) as err:
        read_mesh(tmp_path / name)
    assert "\n" not in str(err.value) and name in str(err.value)


def test_a_missing_mesh_is_named(tmp_path):
    with pytest.raises(MeshError, match="does not exist"):
        read_mesh(tmp_path / "none.obj")


def test_columns_with_an_odd_count_are_cast_again(monkeypatch):
    from ngpm_runtime.volume import voxelize

    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    good = voxelize_mesh(cube.vertices, cube.faces, ORIGIN, STEP, R)
    real = voxelize._cast
    calls = []

    def flaky(tris, r, jitter):
        inside, odd = real(tris, r, jitter)
        calls.append(1)
        if len(calls) == 1:  # the first cast grazes an edge in column (12, 20)
            inside, odd = inside.copy(), odd.copy()
            inside[12, :, 20] = ~inside[12, :, 20]
            odd[12, 20] = True
        return inside, odd

    monkeypatch.setattr(voxelize, "_cast", flaky)
    assert np.array_equal(voxelize_mesh(cube.vertices, cube.faces, ORIGIN, STEP, R), good)
    assert len(calls) == 2

    def always_odd(tris, r, jitter):
        inside, odd = real(tris, r, jitter)
        odd[3, 4] = True
        return inside, odd

    monkeypatch.setattr(voxelize, "_cast", always_odd)
    with pytest.raises(VolumeError, match=r"^box\.obj is not watertight: rays through 1 column"):
        voxelize_mesh(cube.vertices, cube.faces, ORIGIN, STEP, R, "box.obj")
