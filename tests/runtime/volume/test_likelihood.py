"""The voxel likelihood (volume/likelihood.py): the compiled increments against the numpy
reference, increments that sum to the log-likelihood from scratch, the blank value, the
3D bounds terms and the 3D Sobel weights."""

from __future__ import annotations

import numpy as np
import pytest
from fixtures.volume3d import GRID, ball_target, box_target, near, random_prim3
from ngpm_runtime.errors import TargetError
from ngpm_runtime.volume.likelihood import (
    VoxelLikelihood,
    empty_box3,
    sobel3,
    volume_bounds_penalty,
    volume_similarity,
    volume_weights,
)
from ngpm_runtime.volume.raster import VoxelCanvas, voxelize
from ngpm_runtime.volume.target import VolumeTarget
from reference import volume as ref

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")
TOP = np.array(GRID.lo) + GRID.extent()
BOX = (GRID.lo[0], TOP[0], GRID.lo[1], TOP[1], GRID.lo[2], TOP[2])  # the grid's own box
SMALL_BOX = (-2.0, 2.0, 0.0, 4.0, -2.0, 1.0)  # some primitives overhang it


def _finite_prim(rng: np.random.Generator) -> tuple:
    while True:
        p = random_prim3(rng)
        flat = [v for v in p[1:] if not isinstance(v, tuple)] + [
            c for v in p[1:] if isinstance(v, tuple) for q in v for c in q
        ]
        if all(np.isfinite(flat)) and max(abs(v) for v in flat) < 1e6:
            return p


@pytest.mark.parametrize(
    ("seed", "box", "sigma"), [(0, BOX, 0.02), (1, SMALL_BOX, 0.02), (2, BOX, 0.3)]
)
def test_increments_match_the_reference_and_sum_to_the_full_score(seed, box, sigma) -> None:
    rng = np.random.default_rng(seed)
    target = ball_target(GRID, (-1.0, 2.5, -0.5), 2.2)
    like = VoxelLikelihood(target, box, sigma=sigma)
    n = 4
    canvas = VoxelCanvas(n, GRID, pyramid=False)
    state, want_state = like.start(n), like.start(n)
    drawn: list[list[tuple]] = [[] for _ in range(n)]
    total = np.zeros(n)
    for _ in range(10):
        idx = np.sort(rng.choice(n, size=int(rng.integers(1, n + 1)), replace=False))
        prims = [_finite_prim(rng) for _ in idx]
        batch = canvas.draw(idx, prims)
        got = like.increment(state, canvas, batch)
        want = ref.increment(want_state, like, idx, batch.bbox, batch.hit_k, batch.hit_vox)
        np.testing.assert_array_equal(got, want)
        for key in state:
            np.testing.assert_array_equal(state[key], want_state[key])
        total[idx] += got
        for i, p in zip(idx, prims, strict=True):
            drawn[i].append(p)
    for i in range(n):
        if not drawn[i]:
            continue
        vox = voxelize(drawn[i], GRID)
        np.testing.assert_array_equal(vox, canvas.voxels[i])
        boxes = np.array([ref.prim_box(p) for p in drawn[i]])
        bbox = np.concatenate([boxes[:, :3].min(axis=0), boxes[:, 3:].max(axis=0)])
        assert near(total[i], like.full(vox, bbox)), (total[i], like.full(vox, bbox))
    if box is SMALL_BOX:  # the bounds terms were charged
        assert min(volume_bounds_penalty(state["bbox"][i], box) for i in range(n)) < -1.0


def test_blank_perfect_and_bounds_values() -> None:
    target = box_target(GRID, (-2.0, 0.0, -1.5), (0.0, 3.0, 0.5))
    like = VoxelLikelihood(target, BOX)
    assert like.blank_loglik(0, 0) == pytest.approx(-((1 / 0.02) ** 2))
    occ = target.occupancy.astype(np.uint8)
    assert volume_similarity(occ, target.occupancy) == 1.0
    assert volume_similarity(np.zeros_like(occ), target.occupancy) == 0.0
    assert volume_similarity(1 - occ, target.occupancy) < 0
    # overhanging the box by 1% of its extent along y costs (0.01 / 0.001)^2
    b = np.array([-1.0, BOX[2] - 0.01 * (BOX[3] - BOX[2]), 0.0, 1.0, 1.0, 0.2])
    assert volume_bounds_penalty(b, BOX) == pytest.approx(-100.0)
    assert volume_bounds_penalty(empty_box3(1)[0], BOX) == 0.0
    empty = VolumeTarget(
        np.zeros(GRID.shape, bool), np.array(GRID.lo), GRID.voxel, np.zeros(3), "e"
    )
    with pytest.raises(TargetError, match="empty"):
        VoxelLikelihood(empty, BOX)


def test_sobel3_reads_one_on_a_flat_face_and_weights_the_boundary() -> None:
    grid = np.zeros((6, 6, 6))
    grid[:, :3] = 1.0  # a half space below y = 3
    s = sobel3(grid)
    np.testing.assert_allclose(s[1:5, 2:4, 1:5], 1.0)  # the voxels each side of the face
    assert s[3, 1, 3] == 0.0 and s[3, 4, 3] == 0.0  # off the face (y = 0 borders the padding)
    blob = np.zeros((7, 7, 7), bool)
    blob[1:6, 1:6, 1:6] = True
    w = volume_weights(blob)
    assert w[3, 3, 3] == pytest.approx(1 / 1.5)  # inside: flat
    assert w[1, 3, 3] == pytest.approx(1.0)  # on the boundary: like an empty voxel
    assert w[0, 0, 0] == 1.0 and (w[blob] < 1.0 + 1e-12).all()
