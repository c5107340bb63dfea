"""The voxel canvas (volume/raster.py): the compiled draw kernel against the numpy reference
(tests/reference/volume.py) on many seeded random primitives, odd ones included; count
pyramids against counts from scratch; resampling copies; the least thickness."""

from __future__ import annotations

import math

import numpy as np
import pytest
from fixtures.volume3d import GRID, random_prim3
from ngpm_runtime.errors import ProgramError
from ngpm_runtime.volume.raster import (
    MIN_RADIUS,
    VoxelCanvas,
    VoxelGrid,
    pyramid_layout,
    volume_pyramid,
    voxelize,
)
from ngpm_runtime.volume.target import box_grid
from reference import volume as ref

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")


@pytest.mark.parametrize("seed", range(6))
def test_draw_matches_the_numpy_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 5
    canvas = VoxelCanvas(n, GRID)
    want = np.zeros((n, *GRID.shape), dtype=np.uint8)
    drew = 0
    for _ in range(12):
        k = int(rng.integers(1, 8))
        idx = rng.integers(0, n, size=k)  # repeated particles draw in turn
        prims = [random_prim3(rng) for _ in range(k)]
        got = canvas.draw(idx, prims)
        boxes, hit_k, hit_vox = ref.draw(want, GRID, idx, prims)
        np.testing.assert_array_equal(got.bbox, boxes)
        np.testing.assert_array_equal(got.hit_k, hit_k)
        np.testing.assert_array_equal(got.hit_vox, hit_vox)
        np.testing.assert_array_equal(canvas.voxels, want)
        drew += len(hit_k)
    assert drew > 30  # the primitives did cover voxels
    for i in range(n):
        np.testing.assert_array_equal(canvas.counts[i], ref.count_row(canvas.voxels[i]))
        for got_lv, want_lv in zip(canvas.levels(i), volume_pyramid(canvas.voxels[i]), strict=True):
            np.testing.assert_array_equal(got_lv, want_lv)


def test_take_copies_canvases_and_counts() -> None:
    rng = np.random.default_rng(3)
    canvas = VoxelCanvas(4, GRID)
    canvas.draw(np.arange(4), [random_prim3(rng) for _ in range(4)])
    vox, counts = canvas.voxels.copy(), canvas.counts.copy()
    for anc in (np.array([2, 2, 0, 3]), np.array([1, 0, 0, 0])):
        canvas.take(anc)
        np.testing.assert_array_equal(canvas.voxels, vox[anc])
        np.testing.assert_array_equal(canvas.counts, counts[anc])
        vox, counts = vox[anc], counts[anc]
    canvas.take(np.array([0, 1]))  # another population size
    assert canvas.n == 2 and canvas.voxels.shape[0] == 2


def test_thin_primitives_cover_the_voxels_they_pass_through() -> None:
    grid = VoxelGrid((-4.0, -4.0, -4.0), 1.0, (8, 8, 8))
    # a hair-thin vertical segment on the corner of four voxel columns: all four, full height
    vox = voxelize([("seg3", 0.0, -4.0, 0.0, 0.0, 4.0, 0.0, 0.01, 0)], grid)
    assert vox.sum() == 4 * 8 and vox[3:5, :, 3:5].all()
    # along a column's centre: that column only (the least radius is below one voxel)
    vox = voxelize([("seg3", 0.5, -4.0, 0.5, 0.5, 4.0, 0.5, 0.01, 0)], grid)
    assert vox.sum() == 8 and vox[4, :, 4].all()
    # a wide segment is as wide as it says
    vox = voxelize([("seg3", 0.5, -4.0, 0.5, 0.5, 4.0, 0.5, 4.0, 0)], grid)
    assert vox[:, 3].sum() == sum(
        (i - 4) ** 2 + (k - 4) ** 2 < 4 for i in range(8) for k in range(8)
    )
    # a ball: the voxels whose centres lie inside; a leaf lies in its plane (H x L = +z)
    ball = voxelize([("sphere", 0.0, 0.0, 0.0, 3.0, 0)], grid)
    c = np.arange(8) - 3.5
    assert ball.sum() == ((c[:, None, None] ** 2 + c[:, None] ** 2 + c**2) < 9).sum() > 100
    leaf = voxelize([("leaf3", -3.0, 0.5, 0.5, 1, 0, 0, 0, 1, 0, 6.0, 2.0, 0)], grid)
    assert set(np.nonzero(leaf)[2]) == {4} and leaf.sum() >= 6
    # a polygon: a square in the plane z = 0.5, one voxel thick, and a degenerate one
    square = ((-2.0, -2.0, 0.5), (2.0, -2.0, 0.5), (2.0, 2.0, 0.5), (-2.0, 2.0, 0.5))
    face = voxelize([("poly3", square, 0)], grid)
    assert set(np.nonzero(face)[2]) == {4} and face[2:6, 2:6, 4].all()
    line = voxelize([("poly3", ((0.5, 0.5, 0.5), (2.5, 0.5, 0.5), (1.5, 0.5, 0.5)), 0)], grid)
    assert line.sum() == 3 and line[4:7, 4, 4].all()
    assert MIN_RADIUS == pytest.approx(math.sqrt(3) / 2)


def test_pyramid_layout_floors_odd_sizes() -> None:
    sizes, starts, cells = pyramid_layout((12, 14, 10))
    assert sizes.tolist() == [[12, 14, 10], [6, 7, 5], [3, 3, 2], [1, 1, 1]]
    assert starts.tolist() == [0, 0, 210, 228] and cells == 229
    assert VoxelCanvas(2, GRID, pyramid=False).counts.shape == (2, 0)


def test_grids_of_boxes_and_bad_targets() -> None:
    from ngpm_runtime.errors import TargetError
    from ngpm_runtime.volume.target import VolumeTarget

    g = VoxelGrid.of_box((-600, 600, -20, 1150, -600, 600), 32)
    assert g.shape == (32, 32, 32) and g.voxel == pytest.approx(1200 / 32)
    assert g.lo[0] + 16 * g.voxel == pytest.approx(0.0)  # centred on the box in x and z
    assert g.lo[1] == -20.0  # its floor on the box's floor, as targets' grids
    lo, voxel = box_grid((-600, 600, -20, 1150, -600, 600), 32)
    assert g == VoxelGrid((lo[0], lo[1], lo[2]), voxel, (32, 32, 32))
    with pytest.raises(ProgramError, match="cannot lay a voxel grid"):
        VoxelGrid.of_box((0, 0, 0, 0, 0, 0), 8)
    with pytest.raises(TargetError, match=r"occupancy must be \(R, R, R\)"):
        VoxelGrid.of_target(VolumeTarget(np.ones((4, 4)), np.zeros(3), 1.0, np.zeros(3), "flat"))
