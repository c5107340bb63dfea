"""The paper's equation 1 on voxels (docs/3d.md, "Growing into a volume"), incremental.

sim(V, T) = sum_v w(v) [V(v) == T(v)] / sum_v w(v) over the target's grid, w(v) = 1 where the
target is empty, else flat + (1 - flat) * min(1, sobel3(T)(v)) with flat = 1 / 1.5, as in 2D
(inference/likelihood.py). sobel3 is the 3x3x3 Sobel operator: per axis the derivative
[-1, 0, 1] smoothed by [1, 2, 1] along the other two axes, zero padding, magnitude
sqrt(gx^2 + gy^2 + gz^2) / 16, so that a flat face of a 0/1 grid reads 1. Normalized the
same way: simNorm = (sim - sim(blank)) / (1 - sim(blank)); log-likelihood = -(simNorm - 1)^2
/ 0.02^2 plus the bounds terms -(extra / 0.001)^2 along x, y and z, extra being how far the
drawing's world box overhangs the program's `box` over the box's extent.

Covering voxel v changes sim by gain(v) = w(v) (2 T(v) - 1) / sum w / (1 - sim(blank)), so an
increment sums the gains of the voxels a primitive newly covers (volume/kernels.py); the sum
of a particle's increments is its log-likelihood from scratch (`VoxelLikelihood.full`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ngpm_runtime.errors import TargetError
from ngpm_runtime.inference.likelihood import BOUNDS_SCALE, FLAT, SHAPE_SIGMA, Likelihood
from ngpm_runtime.volume.raster import Box, VoxelBatch, VoxelCanvas, VoxelGrid


def sobel3(grid: np.ndarray) -> np.ndarray:
    """3D Sobel gradient magnitude / 16 of an (nx, ny, nz) grid, zero padding."""
    p = np.pad(np.asarray(grid, dtype=np.float64), 1)

    def cut(a: np.ndarray, axis: int, start: int, stop: int) -> np.ndarray:
        index = [slice(None)] * a.ndim
        index[axis] = slice(start, a.shape[axis] - 2 + stop)
        out: np.ndarray = a[tuple(index)]
        return out

    def smooth(a: np.ndarray, axis: int) -> np.ndarray:
        out: np.ndarray = cut(a, axis, 0, 0) + 2.0 * cut(a, axis, 1, 1) + cut(a, axis, 2, 2)
        return out

    def deriv(a: np.ndarray, axis: int) -> np.ndarray:
        out: np.ndarray = cut(a, axis, 2, 2) - cut(a, axis, 0, 0)
        return out

    g = [
        smooth(smooth(deriv(p, 0), 1), 2),
        smooth(smooth(deriv(p, 1), 0), 2),
        smooth(smooth(deriv(p, 2), 0), 1),
    ]
    out: np.ndarray = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) / 16.0
    return out


def volume_weights(occupancy: np.ndarray) -> np.ndarray:
    """w(v): 1 where the target is empty, else flat + (1 - flat) * min(1, sobel3(T))."""
    t = np.asarray(occupancy, dtype=bool)
    edge = np.minimum(sobel3(t), 1.0)
    return np.where(t, FLAT + (1.0 - FLAT) * edge, 1.0)


def _blank_sim(w: np.ndarray, t: np.ndarray) -> tuple[float, float]:
    total = float(w.sum())
    sim0 = float(w[~t].sum()) / total
    if not 1.0 - sim0 > 0.0:
        raise TargetError("3D target is empty: the voxel likelihood needs filled voxels")
    return sim0, total


def volume_similarity(
    occupancy: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None
) -> float:
    """Normalized weighted similarity of an occupancy grid to the target's, 1 = equal,
    0 = no better than an empty grid; `weights`: the target's `volume_weights` when known."""
    t = np.asarray(target, dtype=bool)
    v = np.asarray(occupancy).astype(bool)
    if v.shape != t.shape:
        raise ValueError(f"grid {v.shape} and target {t.shape} differ in size")
    w = volume_weights(t) if weights is None else weights
    sim0, total = _blank_sim(w, t)
    return (float(w[v == t].sum()) / total - sim0) / (1.0 - sim0)


def volume_bounds_penalty(bbox: np.ndarray, box: Box) -> float:
    """-(extra / 0.001)^2 summed over x, y, z for a world box (xmin, ymin, zmin, xmax, ymax,
    zmax) against the program's box (xmin, xmax, ymin, ymax, zmin, zmax); 0 for an empty box
    (+-inf: nothing drawn)."""
    b = np.asarray(bbox, dtype=np.float64)
    if not b[0] <= b[3]:
        return 0.0
    value = 0.0
    for a in range(3):
        lo, hi = box[2 * a], box[2 * a + 1]
        extra = (max(lo - b[a], 0.0) + max(b[3 + a] - hi, 0.0)) / (hi - lo)
        value -= (extra / BOUNDS_SCALE) ** 2
    return value


def empty_box3(n: int) -> np.ndarray:
    """n world boxes holding nothing yet (+inf mins, -inf maxes)."""
    out = np.empty((n, 6))
    out[:, :3] = np.inf
    out[:, 3:] = -np.inf
    return out


def check_box(box: Any, name: str) -> Box:
    """A program's 3D box as six floats (TargetError when it is missing or empty)."""
    if box is None or len(box) != 6:
        raise TargetError(
            f"grammar {name} has no 3D viewport: add 'viewport: XMIN XMAX YMIN YMAX ZMIN ZMAX'"
        )
    b = tuple(float(v) for v in box)
    if not all(b[2 * a + 1] > b[2 * a] for a in range(3)):
        raise TargetError(f"grammar {name}: empty 3D viewport {b}")
    return (b[0], b[1], b[2], b[3], b[4], b[5])


class VoxelLikelihood(Likelihood):
    """Equation 1 against a VolumeTarget (volume/target.py), on a VoxelCanvas of the
    target's grid; the bounds terms against the program's 3D box. `sigma` is the equation's
    0.02 (a larger one tempers the likelihood: the exactness tests use one)."""

    needs_canvas = True

    def __init__(self, target: Any, box: Box, sigma: float = SHAPE_SIGMA) -> None:
        self.sigma = float(sigma)
        self.grid = VoxelGrid.of_target(target)
        self.source = target
        t = np.asarray(target.occupancy, dtype=bool)
        self.target = t
        self.box = check_box(box, str(target.name))
        w = volume_weights(t)
        self.weights = w
        self.sim_blank, total = _blank_sim(w, t)
        self.gain = (w * (2.0 * t - 1.0) / total / (1.0 - self.sim_blank)).reshape(-1)
        self._box = np.array(self.box)
        from ngpm_runtime.volume import kernels

        self._k = kernels

    def start(self, n: int) -> dict[str, np.ndarray]:
        return {"sim": np.zeros(n), "bbox": empty_box3(n), "ll": np.zeros(n)}

    def increment(
        self, state: dict[str, np.ndarray], canvas: VoxelCanvas, batch: VoxelBatch
    ) -> np.ndarray:
        if canvas.grid != self.grid:
            raise TargetError(f"voxel canvas {canvas.grid} is not the target's {self.grid}")
        delta: np.ndarray = self._k.volume_increment(
            state["sim"],
            state["bbox"],
            state["ll"],
            batch.idx,
            batch.hit_k,
            batch.hit_vox,
            self.gain,
            batch.bbox,
            self._box,
            self.sigma,
        )
        return delta

    def full(self, occupancy: np.ndarray, bbox: np.ndarray) -> float:
        """Log-likelihood of one finished grid from scratch."""
        s = self.similarity(occupancy)
        return float(-(((s - 1.0) / self.sigma) ** 2) + volume_bounds_penalty(bbox, self.box))

    def similarity(self, occupancy: np.ndarray) -> float:
        """`volume_similarity` of a grid to the target (its weights computed once)."""
        return volume_similarity(occupancy, self.target, self.weights)

    def blank_loglik(self, height: int, width: int) -> float | None:
        """The empty grid's value (the arguments, a 2D canvas's size, are not used)."""
        value = self.full(np.zeros(self.target.shape, dtype=np.uint8), empty_box3(1)[0])
        return value if not math.isnan(value) else -math.inf
