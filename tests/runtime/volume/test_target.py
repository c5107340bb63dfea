"""VolumeTarget (ngpm_runtime.volume.target): checks, indices, boundary, .npz files."""

from __future__ import annotations

import numpy as np
import pytest
from ngpm_runtime.volume.target import (
    VolumeError,
    VolumeTarget,
    boundary,
    box_grid,
    voxel_mesh,
)


def ball(r: int = 16) -> VolumeTarget:
    c = np.arange(r) + 0.5 - r / 2
    occ = c[:, None, None] ** 2 + c[None, :, None] ** 2 + c[None, None, :] ** 2 < (r / 3) ** 2
    return VolumeTarget(occ, [-8.0, 0.0, -8.0], 1.0, [0.0, 2.0, 0.0], "ball")


def test_fields_are_checked_and_converted():
    t = ball()
    assert t.occupancy.dtype == bool and t.resolution == 16
    assert t.lo.dtype == np.float64 and t.start.tolist() == [0.0, 2.0, 0.0]
    assert t.hi.tolist() == [8.0, 16.0, 8.0]
    with pytest.raises(VolumeError, match=r"occupancy must be \(R, R, R\)"):
        VolumeTarget(np.zeros((4, 4, 5)), np.zeros(3), 1.0, np.zeros(3))
    with pytest.raises(VolumeError, match="voxel must be a positive"):
        VolumeTarget(np.zeros((4, 4, 4)), np.zeros(3), 0.0, np.zeros(3))
    with pytest.raises(VolumeError, match="start must be three finite numbers"):
        VolumeTarget(np.zeros((4, 4, 4)), np.zeros(3), 1.0, [0, np.nan, 0])


def test_world_and_index_round_trip():
    t = ball()
    idx = np.array([[0, 0, 0], [15, 3, 7]])
    world = t.index_to_world(idx)
    assert world[0].tolist() == [-7.5, 0.5, -7.5]
    assert np.array_equal(t.world_to_index(world), idx)
    assert t.world_to_index([8.0, 0.0, 0.0]).tolist() == [16, 0, 8]
    assert t.inside(np.array([[16, 0, 8], [15, 0, 8], [0, -1, 0]])).tolist() == [False, True, False]


def test_boundary_is_the_filled_voxels_with_an_empty_neighbour():
    occ = np.zeros((5, 5, 5), dtype=bool)
    occ[1:4, 1:4, 1:4] = True
    b = boundary(occ)
    assert b.sum() == 27 - 1 and not b[2, 2, 2]
    full = np.ones((3, 3, 3), dtype=bool)
    assert boundary(full).sum() == 26  # the grid's outside counts as empty
    assert ball().boundary().sum() < ball().occupancy.sum()


def test_npz_round_trip_and_bad_files(tmp_path):
    t = ball()
    path = t.to_npz(tmp_path / "ball.npz")
    back = VolumeTarget.from_npz(path)
    assert np.array_equal(back.occupancy, t.occupancy)
    assert np.array_equal(back.lo, t.lo) and back.voxel == t.voxel
    assert np.array_equal(back.start, t.start) and back.name == "ball"
    assert [p.name for p in tmp_path.iterdir()] == ["ball.npz"]  # no temporary left
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(VolumeError, match=r"^cannot read 3D target .*bad\.npz"):
        VolumeTarget.from_npz(tmp_path / "bad.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(VolumeError, match="other.npz"):
        VolumeTarget.from_npz(tmp_path / "other.npz")
    with pytest.raises(VolumeError, match="does not exist"):
        VolumeTarget.from_npz(tmp_path / "none.npz")


def test_box_grid_is_a_cube_on_the_box_floor():
    lo, voxel = box_grid((-600, 600, -20, 1150, -500, 500), 32)
    assert lo.tolist() == [-600.0, -20.0, -600.0] and voxel == 1200 / 32
    lo, voxel = box_grid((0, 1, 0, 4, 0, 2), 8)
    assert lo.tolist() == [-1.5, 0.0, -1.0] and voxel == 0.5
    with pytest.raises(VolumeError, match="no extent"):
        box_grid((0, 0, 0, 0, 0, 0))


def test_voxel_mesh_is_closed_with_outward_faces():
    occ = np.zeros((3, 3, 3), dtype=bool)
    occ[0, 0, 0] = occ[1, 0, 0] = True
    mesh = voxel_mesh(occ, np.array([1.0, 2.0, 3.0]), 0.5)
    assert len(mesh.faces) == 2 * 10  # two voxels side by side: 10 outer faces
    tri = mesh.vertices[mesh.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = tri.mean(axis=1) - np.array([1.5, 2.25, 3.25])  # from the pair's middle
    assert np.all(np.sum(normal * outward, axis=1) > 0)
    assert mesh.bounds.tolist() == [[1.0, 2.0, 3.0], [2.0, 2.5, 3.5]]
