"""Voxelization of 3D primitives into per-particle occupancy grids (docs/3d.md, "Growing
into a volume"), the 3D counterpart of image/raster.py.

A grid is `VoxelGrid(lo, voxel, shape)`: voxel (ix, iy, iz) has its centre at
lo + (ix + 0.5, iy + 0.5, iz + 0.5) * voxel, along world x, y (up) and z, as a
`VolumeTarget`'s occupancy. A voxel is covered when its centre lies strictly inside the
primitive, each primitive made at least `MIN_RADIUS` voxels thick: a segment is a capsule of
radius max(width / 2, MIN_RADIUS * voxel), a sphere a ball, a leaf an elliptic disc and a
polygon a plane slab (plus its edges as capsules) of that half thickness. So every voxel a
primitive passes through is covered (sqrt(3) / 2 is half a voxel's diagonal), and a branch
far thinner than a voxel still shows.

`VoxelCanvas.draw` voxelizes one primitive per listed particle in one compiled call
(volume/kernels.py) and, when guide features are served, keeps a count pyramid per
particle: for levels 1-3 the number of covered voxels in each 2x2x2, 4x4x4 and 8x8x8 block
(floor sizes), in one uint16 row (`pyramid_layout`). Voxels are only ever added, so each
level just counts up.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ngpm_runtime.errors import ProgramError, TargetError
from ngpm_runtime.geometry.turtle import Prim

N_LEVELS = 4
MIN_RADIUS = 0.5 * 3.0**0.5  # voxels: half a voxel's diagonal
DEFAULT_RESOLUTION = 32  # voxels along the longest side of the box, without a target
Box = tuple[float, float, float, float, float, float]  # (xmin, xmax, ymin, ymax, zmin, zmax)
_CODES = {"seg3": 0, "sphere": 1, "leaf3": 2, "poly3": 3}  # kernels SEG3, SPHERE, ...
_NO_VERTS = np.zeros((0, 3))
_N_PAR = 11


@dataclass(frozen=True)
class VoxelGrid:
    """Where the voxels lie: min corner `lo` (3,), edge length `voxel`, `shape` (nx, ny, nz)."""

    lo: tuple[float, float, float]
    voxel: float
    shape: tuple[int, int, int]

    @classmethod
    def of_target(cls, target: Any) -> VoxelGrid:
        """The grid of a VolumeTarget (TargetError for one that cannot be used)."""
        occ = np.asarray(target.occupancy)
        lo = np.asarray(target.lo, dtype=np.float64).reshape(-1)
        voxel = float(target.voxel)
        if occ.ndim != 3 or min(occ.shape) < 1:
            raise TargetError(f"3D target {target.name!r}: occupancy must be 3D, got {occ.shape}")
        if lo.shape != (3,) or not np.isfinite(lo).all() or not (0 < voxel < np.inf):
            raise TargetError(f"3D target {target.name!r}: needs a finite lo (3,) and voxel > 0")
        x, y, z = (int(s) for s in occ.shape)
        return cls((float(lo[0]), float(lo[1]), float(lo[2])), voxel, (x, y, z))

    @classmethod
    def of_box(cls, box: Sequence[float], resolution: int = DEFAULT_RESOLUTION) -> VoxelGrid:
        """The grid of a run without a target: the cube of `resolution`^3 voxels that
        targets are placed on (`volume.target.box_grid`: its side the box's longest, centred
        on the box in x and z, its floor the box's floor)."""
        from ngpm_runtime.volume.target import VolumeError, box_grid

        b = [float(v) for v in box]
        try:
            if resolution < 1:
                raise VolumeError("no voxels")
            lo, voxel = box_grid(b, resolution)
        except VolumeError:
            raise ProgramError(f"cannot lay a voxel grid over the box {tuple(b)}") from None
        return cls((float(lo[0]), float(lo[1]), float(lo[2])), voxel, (resolution,) * 3)

    def centres(self, axis: int) -> np.ndarray:
        """The voxel centres' world coordinates along one axis."""
        return self.lo[axis] + (np.arange(self.shape[axis]) + 0.5) * self.voxel

    def extent(self) -> np.ndarray:
        """The grid's size along x, y and z in world units."""
        return np.array(self.shape, dtype=np.float64) * self.voxel


@dataclass
class VoxelBatch:
    """What one `VoxelCanvas.draw` call changed: per batch row k, particle `idx[k]`, the
    primitive's world box `bbox[k]` (xmin, ymin, zmin, xmax, ymax, zmax); the new voxels as
    `hit_k` (batch row) and `hit_vox` (flat index (ix * ny + iy) * nz + iz)."""

    idx: np.ndarray
    bbox: np.ndarray
    hit_k: np.ndarray
    hit_vox: np.ndarray
    prims: list[Prim] | None = None  # the drawn primitives (smc sets them)


def pyramid_layout(shape: Sequence[int]) -> tuple[np.ndarray, np.ndarray, int]:
    """Levels 0-3 of a grid: sizes (4, 3) (floor halvings) and starts (4,) in a count row
    holding levels 1-3 one after another (level 0 is the canvas itself: start 0, unused),
    and the row's length."""
    sizes = np.array([[int(s) >> lv for s in shape] for lv in range(N_LEVELS)], dtype=np.int64)
    cells = sizes.prod(axis=1)
    starts = np.zeros(N_LEVELS, dtype=np.int64)
    starts[2:] = np.cumsum(cells[1:-1])
    return sizes, starts, int(cells[1:].sum())


def volume_pyramid(occupancy: np.ndarray) -> list[np.ndarray]:
    """4 levels of 2x2x2 means of an (..., nx, ny, nz) grid (float32), from scratch."""
    cur = np.asarray(occupancy, dtype=np.float64)
    out = [cur.astype(np.float32)]
    for _ in range(1, N_LEVELS):
        x, y, z = (s // 2 for s in cur.shape[-3:])
        c = cur[..., : 2 * x, : 2 * y, : 2 * z]
        c = c.reshape(c.shape[:-3] + (x, 2, y, 2, z, 2))
        cur = c.mean(axis=(-5, -3, -1))
        out.append(cur.astype(np.float32))
    return out


def _kernels() -> Any:
    """The compiled 3D kernels, imported on first use (numba loads when something is drawn)."""
    from ngpm_runtime.volume import kernels

    return kernels


def pack(prims: list[Prim]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """3D primitives as `kernels.draw` takes them: kind codes (n,), parameters (n, 11) (all
    but the kind and the colour), polygon vertices (m, 3), each primitive's first vertex
    (n + 1,)."""
    n = len(prims)
    if n and all(p[0] == "seg3" for p in prims):  # the common case: one row each
        seg = np.zeros((n, _N_PAR))
        seg[:, :7] = np.array([p[1:8] for p in prims], dtype=np.float64)
        return np.zeros(n, dtype=np.int8), seg, _NO_VERTS, np.zeros(n + 1, dtype=np.intp)
    codes = np.empty(n, dtype=np.int8)
    par = np.zeros((n, _N_PAR))
    verts: list[np.ndarray] = []
    vstart = np.zeros(n + 1, dtype=np.intp)
    for k, p in enumerate(prims):
        code = _CODES.get(p[0])
        if code is None:
            raise ValueError(f"not a 3D primitive: {p[0]!r}")
        codes[k] = code
        if code == 3:
            v = np.asarray(p[1], dtype=np.float64).reshape(-1, 3)
            verts.append(v)
            vstart[k + 1] = vstart[k] + len(v)
        else:
            par[k, : len(p) - 2] = p[1:-1]
            vstart[k + 1] = vstart[k]
    return codes, par, np.concatenate(verts) if verts else _NO_VERTS, vstart


class VoxelCanvas:
    """N occupancy grids `voxels` (N, nx, ny, nz) uint8 with their count pyramids `counts`
    (N, P) uint16 (`pyramid_layout`; P == 0 with `pyramid=False`)."""

    def __init__(self, n: int, grid: VoxelGrid, pyramid: bool = True) -> None:
        self.n, self.grid = int(n), grid
        self._k = _kernels()
        self.voxels = np.zeros((self.n, *grid.shape), dtype=np.uint8)
        self.sizes, self.starts, cells = pyramid_layout(grid.shape)
        self.pyramid = pyramid
        self.counts = np.zeros((self.n, cells if pyramid else 0), dtype=np.uint16)
        self._grid = np.array([*grid.lo, grid.voxel, MIN_RADIUS * grid.voxel])
        self._spare: list[np.ndarray] | None = None

    @property
    def height(self) -> int:
        """The grid's y size (what SMC passes `blank_loglik` as the height)."""
        return self.grid.shape[1]

    @property
    def width(self) -> int:
        """The grid's x size (what SMC passes `blank_loglik` as the width)."""
        return self.grid.shape[0]

    def levels(self, i: int) -> list[np.ndarray]:
        """Canvas i's pyramid as means (float32, levels 0-3), for checks and pictures."""
        out = [self.voxels[i].astype(np.float32)]
        for lv in range(1, N_LEVELS):
            x, y, z = (int(s) for s in self.sizes[lv])
            st = int(self.starts[lv])
            row = self.counts[i, st : st + x * y * z].reshape(x, y, z)
            out.append(row.astype(np.float32) * np.float32(1.0 / 8.0**lv))
        return out

    def draw(self, idx: np.ndarray, prims: list[Prim]) -> VoxelBatch:
        """Voxelize `prims[k]` into canvas `idx[k]` (one compiled call; a repeated index
        draws its primitives in turn); returns the changes."""
        idx = np.asarray(idx, dtype=np.intp).reshape(-1)
        if len(prims) != len(idx):
            raise ValueError("draw: one primitive per listed particle")
        codes, par, verts, vstart = pack(prims)
        bbox, hit_k, hit_vox = self._k.draw(
            self.voxels, self.counts, self.starts, idx, codes, par, verts, vstart, self._grid
        )
        return VoxelBatch(idx=idx, bbox=bbox, hit_k=hit_k, hit_vox=hit_vox)

    def take(self, idx: np.ndarray) -> None:
        """Resampling: particle k becomes old particle idx[k] (double-buffered copies, as
        image/raster.Canvas.take)."""
        idx = np.asarray(idx, dtype=np.intp).reshape(-1)
        if len(idx) != self.n:
            self.voxels, self.counts = self.voxels[idx], self.counts[idx]
            self.n, self._spare = len(idx), None
            return
        if self._spare is None:
            self._spare = [np.empty_like(self.voxels), np.empty_like(self.counts)]
        vox, cnt = self._spare
        n = self.n
        from ngpm_runtime import kernels  # its take_rows copies any rows, voxels too

        kernels.take_rows(self.voxels.reshape(n, -1), self.counts, idx, vox.reshape(n, -1), cnt)
        self._spare = [self.voxels, self.counts]
        self.voxels, self.counts = vox, cnt


def voxelize(prims: list[Prim], grid: VoxelGrid, chunk: int = 64) -> np.ndarray:
    """The (nx, ny, nz) uint8 occupancy of all prims (from scratch)."""
    canvas = VoxelCanvas(1, grid, pyramid=False)
    for s in range(0, len(prims), chunk):
        part = prims[s : s + chunk]
        canvas.draw(np.zeros(len(part), dtype=np.intp), part)
    out: np.ndarray = canvas.voxels[0]
    return out


__all__ = [
    "MIN_RADIUS",
    "N_LEVELS",
    "VoxelBatch",
    "VoxelCanvas",
    "VoxelGrid",
    "pack",
    "pyramid_layout",
    "volume_pyramid",
    "voxelize",
]
