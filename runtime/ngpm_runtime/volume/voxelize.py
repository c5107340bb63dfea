"""Shapes -> occupancy on a regular grid of sample points, in numpy.

A grid is given in the shape's own coordinates: sample point (i, j, k) is
`origin + (i + 0.5, j + 0.5, k + 0.5) * step`, i, j, k in 0..R-1 (load.py maps a target's
voxel centres back into the shape this way). Meshes are filled by ray parity: a vertical
ray (along y) through each column of sample points counts the triangles it crosses below
each point, and a point is inside when that count is odd. The rays are moved by a small
seeded jitter so that they do not pass through edges and vertices; a column whose ray
crosses the surface an odd number of times in all is cast again with another jitter, and
the mesh is refused when one stays odd. A mesh whose edges are not all shared by an even
number of triangles (a hole) is refused first.

Pictures: `extrude(mask, depth)` and `revolve(mask)` turn a 2D mask into a lattice (a bool
array of unit cells, [ix, iy, iz], y up); `sample_lattice` resamples a lattice at a grid.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ngpm_runtime.volume.target import VolumeError

JITTER = 0.01  # largest ray offset, in sample spacings
TRIES = 6  # casts of a column before its odd count refuses the mesh
CHUNK = 1 << 19  # (triangle, column) pairs tested at once


def weld(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices at the same place (to 1e-9 of the mesh's size) merged; triangles with two
    equal corners dropped. Returns (vertices, faces)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(v) == 0 or len(f) == 0:
        return v.reshape(-1, 3), f.reshape(-1, 3)
    lo, hi = v.min(axis=0), v.max(axis=0)
    quantum = max(float(np.max(hi - lo)), 1e-300) * 1e-9
    keys = np.round((v - lo) / quantum).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    f = inverse.reshape(-1)[f]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    return v[first], f[keep]


def open_edges(faces: np.ndarray) -> int:
    """How many edges belong to an odd number of triangles (0 for a closed surface)."""
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return 0
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    edges.sort(axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int(np.count_nonzero(counts % 2))


def check_closed(
    vertices: np.ndarray, faces: np.ndarray, name: str
) -> tuple[np.ndarray, np.ndarray]:
    """The welded mesh; VolumeError naming it when empty or not watertight."""
    if len(faces) == 0:
        raise VolumeError(f"{name} holds no triangles")
    v, f = weld(vertices, faces)
    if len(f) == 0:
        raise VolumeError(f"{name} holds no triangles with an area")
    holes = open_edges(f)
    if holes:
        raise VolumeError(
            f"{name} is not watertight: {holes} edge(s) border a hole (each edge must be "
            "shared by two triangles); close it (e.g. Blender's 3D-Print toolbox) first"
        )
    return v, f


def voxelize_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    origin: np.ndarray,
    step: float,
    resolution: int,
    name: str = "mesh",
    seed: int = 0,
) -> np.ndarray:
    """(R, R, R) bool: which sample points lie inside a closed mesh (ray parity along y)."""
    r = int(resolution)
    grid = (np.asarray(vertices, dtype=np.float64) - np.asarray(origin)) / float(step) - 0.5
    tris = grid[np.asarray(faces, dtype=np.int64)]  # sample point i is at i in these units
    rng = np.random.default_rng([seed, r])
    occ = np.zeros((r, r, r), dtype=bool)
    todo = np.ones((r, r), dtype=bool)
    for _ in range(TRIES):
        jitter = rng.uniform(-JITTER, JITTER, size=(2, r, r))
        inside, odd = _cast(tris, r, jitter)
        done = todo & ~odd  # columns (ix, iz) settled by this cast
        occ = np.where(done[:, None, :], inside, occ)
        todo &= odd
        if not todo.any():
            return occ
    raise VolumeError(
        f"{name} is not watertight: rays through {int(todo.sum())} column(s) of the grid "
        "cross its surface an odd number of times"
    )


def _cast(tris: np.ndarray, r: int, jitter: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inside (R, R, R) by parity and the columns (R, R) with an odd number of crossings."""
    toggles = np.zeros(r * (r + 1) * r, dtype=np.int64)
    for ti, ix, iz in _pairs(tris, r):
        t = tris[ti]
        px = ix + jitter[0, ix, iz]
        pz = iz + jitter[1, ix, iz]
        ax, ay, az = t[:, 0, 0], t[:, 0, 1], t[:, 0, 2]
        bx, by, bz = t[:, 1, 0], t[:, 1, 1], t[:, 1, 2]
        cx, cy, cz = t[:, 2, 0], t[:, 2, 1], t[:, 2, 2]
        wa = (cx - bx) * (pz - bz) - (cz - bz) * (px - bx)  # weight of a (opposite edge bc)
        wb = (ax - cx) * (pz - cz) - (az - cz) * (px - cx)
        wc = (bx - ax) * (pz - az) - (bz - az) * (px - ax)
        hit = ((wa > 0) & (wb > 0) & (wc > 0)) | ((wa < 0) & (wb < 0) & (wc < 0))
        if not hit.any():
            continue
        wa, wb, wc = wa[hit], wb[hit], wc[hit]
        y = (wa * ay[hit] + wb * by[hit] + wc * cy[hit]) / (wa + wb + wc)
        # points j with j > y see this crossing below them: it toggles from k = floor(y) + 1
        k = np.clip(np.floor(y).astype(np.int64) + 1, 0, r)
        flat = (ix[hit] * (r + 1) + k) * r + iz[hit]
        toggles += np.bincount(flat, minlength=toggles.size)
    counts = np.cumsum(toggles.reshape(r, r + 1, r), axis=1)
    return (counts[:, :r, :] & 1).astype(bool), (counts[:, r, :] & 1).astype(bool)


def _pairs(tris: np.ndarray, r: int) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Batches (triangle, ix, iz) of the columns inside each triangle's box seen from
    above (widened by the jitter), at most about CHUNK pairs a batch."""
    lo = np.ceil(tris[:, :, [0, 2]].min(axis=1) - JITTER).astype(np.int64)
    hi = np.floor(tris[:, :, [0, 2]].max(axis=1) + JITTER).astype(np.int64)
    lo = np.clip(lo, 0, r)
    hi = np.clip(hi, -1, r - 1)
    span = np.maximum(hi - lo + 1, 0)
    n = span[:, 0] * span[:, 1]
    ends = np.cumsum(n)
    start = 0
    while start < len(tris):
        base = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, base + CHUNK, side="right")), start + 1)
        ti = np.repeat(np.arange(start, stop), n[start:stop])
        if len(ti):
            first = ends[start:stop] - n[start:stop] - base  # of each triangle's pairs
            offset = np.arange(len(ti)) - np.repeat(first, n[start:stop])
            nz = span[ti, 1]
            yield ti, lo[ti, 0] + offset // nz, lo[ti, 1] + offset % nz
        start = stop


def extrude(mask: np.ndarray, depth: int) -> np.ndarray:
    """A picture's mask (H, W), rows top down, pushed `depth` cells along z: a lattice
    (W, H, depth) indexed [ix, iy, iz] with y up."""
    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise VolumeError(f"extrude needs a 2-D mask, got shape {m.shape}")
    depth = int(depth)
    if depth < 1:
        raise VolumeError(f"extrude depth must be at least one cell, got {depth}")
    out: np.ndarray = np.repeat(m[::-1, :].T[:, :, None], depth, axis=2)
    return out


def revolve(mask: np.ndarray) -> np.ndarray:
    """A picture's mask (H, W) turned about the vertical axis through the middle of its
    shape's bounding box: a cell at distance d from the axis, at height h, is filled when
    the mask is, at that height, at d to the left or right of the axis. A lattice (n, H, n)
    indexed [ix, iy, iz] with y up, n the shape's width in pixels."""
    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise VolumeError(f"revolve needs a 2-D mask, got shape {m.shape}")
    c0, c1 = revolve_span(m)
    n = c1 - c0
    axis = (c0 + c1) / 2.0
    c = np.arange(n) + 0.5 - n / 2.0
    dist = np.hypot(c[:, None], c[None, :])  # (n, n) over (ix, iz)
    out = np.zeros((n, m.shape[0], n), dtype=bool)
    for side in (-1.0, 1.0):
        col = np.floor(axis + side * dist).astype(np.int64)
        ok = (col >= c0) & (col < c1)
        picked = m[::-1, :][:, np.clip(col, 0, m.shape[1] - 1)]  # (H, n, n)
        out |= (picked & ok[None]).transpose(1, 0, 2)
    return out


def revolve_span(mask: np.ndarray) -> tuple[int, int]:
    """(first column, last column + 1) of a mask's shape: `revolve` turns it about their
    middle."""
    cols = np.nonzero(np.asarray(mask, dtype=bool).any(axis=0))[0]
    if cols.size == 0:
        raise VolumeError("revolve: the mask is empty")
    return int(cols[0]), int(cols[-1]) + 1


def sample_lattice(
    lattice: np.ndarray, origin: np.ndarray, step: float, resolution: int
) -> np.ndarray:
    """(R, R, R) bool: a lattice of unit cells (cell (i, j, k) covers [i, i + 1) x ...)
    sampled at a grid: each grid voxel takes 2 x 2 x 2 points and is filled when at least
    half of them fall in filled cells (as 2D masks are resized by area)."""
    lat = np.asarray(lattice, dtype=bool)
    r = int(resolution)
    votes = np.zeros((r, r, r), dtype=np.int64)
    for offsets in np.ndindex(2, 2, 2):
        idx = []
        for axis in range(3):
            p = origin[axis] + (np.arange(r) + 0.25 + 0.5 * offsets[axis]) * step
            idx.append(np.floor(p).astype(np.int64))
        okx, oky, okz = ((i >= 0) & (i < lat.shape[a]) for a, i in enumerate(idx))
        clipped = [np.clip(i, 0, lat.shape[a] - 1) for a, i in enumerate(idx)]
        hit = lat[np.ix_(*clipped)] & okx[:, None, None] & oky[None, :, None] & okz[None, None, :]
        votes += hit
    out: np.ndarray = votes >= 4
    return out
