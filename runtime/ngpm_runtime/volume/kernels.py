"""Compiled kernels of growth into a 3D target (numba), each one call over the population.

`draw` (3D primitives -> voxel canvases and their count pyramids), `volume_increment` (the
voxel likelihood's update) and `volume_features` (turtle columns and the windows at 4
levels); resampling copies the voxels with ../kernels.py's `take_rows`.
tests/reference/volume.py holds the numpy code they are compared with: the same arithmetic
in the same order, so canvases, pyramids, likelihoods and feature rows are identical.

Imported lazily (by VoxelCanvas, VoxelLikelihood and FeatureMaker3D), like ../kernels.py,
whose import (done here first) keeps numba's BLAS probe from importing scipy.linalg.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ngpm_runtime import kernels as _base  # noqa: F401  (numba's array typing, no scipy)

N_LEVELS = 4
EPS = 1e-9
SEG3, SPHERE, LEAF3, POLY3 = 0, 1, 2, 3  # primitive kind codes of `draw`
BOUNDS_SCALE = 0.001
jit = njit(cache=True, nogil=True, error_model="numpy")
# _min, _max and _unit repeat ngpm_runtime.kernels' on purpose: numba's disk cache checks
# only this file's stamp, so a kernel here calling one there would keep stale code when that
# file changed. Resampling's copies are ngpm_runtime.kernels.take_rows (called from Python).


@jit
def _min(a: float, b: float) -> float:
    """np.minimum of two floats (a NaN wins)."""
    return a if (a <= b or a != a) else b


@jit
def _max(a: float, b: float) -> float:
    """np.maximum of two floats (a NaN wins)."""
    return a if (a >= b or a != a) else b


@jit
def _box(kind: int, p: np.ndarray, verts: np.ndarray, v0: int, v1: int, out: np.ndarray) -> None:
    """World box (xmin, ymin, zmin, xmax, ymax, zmax) of one primitive (turtle3d's
    prim3_bounds, NaN-propagating)."""
    if kind == SEG3:
        r = abs(p[6]) / 2.0
        for a in range(3):
            out[a] = _min(p[a], p[3 + a]) - r
            out[3 + a] = _max(p[a], p[3 + a]) + r
    elif kind == SPHERE:
        r = abs(p[3])
        for a in range(3):
            out[a] = p[a] - r
            out[3 + a] = p[a] + r
    elif kind == LEAF3:
        ha, hb = p[9] / 2.0, abs(p[10]) / 2.0
        for a in range(3):
            c = p[a] + ha * p[3 + a]
            e = math.sqrt((ha * p[3 + a]) ** 2 + (hb * p[6 + a]) ** 2)
            out[a] = c - e
            out[3 + a] = c + e
    else:
        for a in range(3):
            out[a], out[3 + a] = np.inf, -np.inf
        for v in range(v0, v1):
            for a in range(3):
                if v == v0:
                    out[a], out[3 + a] = verts[v, a], verts[v, a]
                else:
                    out[a] = _min(out[a], verts[v, a])
                    out[3 + a] = _max(out[3 + a], verts[v, a])


@jit
def _range(box: np.ndarray, grid: np.ndarray, reach: float, shape: np.ndarray) -> np.ndarray:
    """First and last voxel (3, 2) whose centre lies within `reach` of the box (clipped to
    the grid; last < first: none). grid = (lo x, lo y, lo z, voxel)."""
    out = np.zeros((3, 2), dtype=np.int64)
    for a in range(3):
        lo = (box[a] - reach - grid[a]) / grid[3] - 0.5 - EPS
        hi = (box[3 + a] + reach - grid[a]) / grid[3] - 0.5 + EPS
        if not (math.isfinite(lo) and math.isfinite(hi)):
            out[a, 0], out[a, 1] = 0, -1
            continue
        lo = _min(_max(lo, -1.0), shape[a] + 1.0)
        hi = _min(_max(hi, -2.0), shape[a] + 1.0)
        out[a, 0] = max(int(math.ceil(lo)), 0)
        out[a, 1] = min(int(math.floor(hi)), shape[a] - 1)
    return out


@jit
def _in_segment(
    x0: float,
    y0: float,
    z0: float,
    x1: float,
    y1: float,
    z1: float,
    r2: float,
    px: float,
    py: float,
    pz: float,
) -> bool:
    """Whether (px, py, pz) is nearer than sqrt(r2) to the segment."""
    ex, ey, ez = x1 - x0, y1 - y0, z1 - z0
    l2 = ex * ex + ey * ey + ez * ez
    inv = 1.0 / l2 if l2 > 0 else 0.0
    dx, dy, dz = px - x0, py - y0, pz - z0
    t = dx * (ex * inv) + dy * (ey * inv) + dz * (ez * inv)
    if t < 0.0:
        t = 0.0
    if t > 1.0:
        t = 1.0
    qx, qy, qz = dx - t * ex, dy - t * ey, dz - t * ez
    hit: bool = qx * qx + qy * qy + qz * qz < r2
    return hit


@jit
def _in_leaf(p: np.ndarray, mr: float, px: float, py: float, pz: float) -> bool:
    """Leaf: within mr of the ellipse's plane (normal H x L) and inside the ellipse of
    semi-axes max(|length| / 2, mr) along H and max(|width| / 2, mr) along L."""
    ha = p[9] / 2.0
    a, b = _max(abs(ha), mr), _max(abs(p[10]) / 2.0, mr)
    dx, dy, dz = px - (p[0] + ha * p[3]), py - (p[1] + ha * p[4]), pz - (p[2] + ha * p[5])
    nx = p[4] * p[8] - p[5] * p[7]
    ny = p[5] * p[6] - p[3] * p[8]
    nz = p[3] * p[7] - p[4] * p[6]
    n = dx * nx + dy * ny + dz * nz
    if not n * n < mr * mr:
        return False
    u = dx * p[3] + dy * p[4] + dz * p[5]
    v = dx * p[6] + dy * p[7] + dz * p[8]
    hit: bool = u * u * (b * b) + v * v * (a * a) < (a * a) * (b * b)
    return hit


@jit
def _face(verts: np.ndarray, v0: int, v1: int) -> np.ndarray:
    """A polygon's unit normal by Newell's method and the axis dropped for the inside test
    (the normal's largest component): (nx, ny, nz, axis); axis -1 when it has no normal."""
    nx, ny, nz = 0.0, 0.0, 0.0
    for i in range(v0, v1):
        j = i + 1 if i + 1 < v1 else v0
        nx += (verts[i, 1] - verts[j, 1]) * (verts[i, 2] + verts[j, 2])
        ny += (verts[i, 2] - verts[j, 2]) * (verts[i, 0] + verts[j, 0])
        nz += (verts[i, 0] - verts[j, 0]) * (verts[i, 1] + verts[j, 1])
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    out = np.array([0.0, 0.0, 0.0, -1.0])
    if v1 - v0 < 3 or not (norm > 0.0 and math.isfinite(norm)):
        return out
    out[0], out[1], out[2] = nx / norm, ny / norm, nz / norm
    ax, ay, az = abs(out[0]), abs(out[1]), abs(out[2])
    out[3] = 0.0 if (ax >= ay and ax >= az) else (1.0 if ay >= az else 2.0)
    return out


@jit
def _in_poly(
    verts: np.ndarray,
    v0: int,
    v1: int,
    face: np.ndarray,
    mr: float,
    px: float,
    py: float,
    pz: float,
) -> bool:
    """Polygon: within mr of an edge, or within mr of its plane and inside it (seen along
    the dropped axis; the even-odd rule)."""
    r2 = mr * mr
    for i in range(v0, v1):
        j = i + 1 if i + 1 < v1 else v0
        if _in_segment(
            verts[i, 0],
            verts[i, 1],
            verts[i, 2],
            verts[j, 0],
            verts[j, 1],
            verts[j, 2],
            r2,
            px,
            py,
            pz,
        ):
            return True
    drop = int(face[3])
    if drop < 0:
        return False
    d = (
        (px - verts[v0, 0]) * face[0]
        + (py - verts[v0, 1]) * face[1]
        + (pz - verts[v0, 2]) * face[2]
    )
    if not d * d < r2:
        return False
    a, b = (1, 2) if drop == 0 else ((2, 0) if drop == 1 else (0, 1))
    pt = (px, py, pz)
    x, y = pt[a], pt[b]
    inside = False
    for i in range(v0, v1):
        j = i - 1 if i > v0 else v1 - 1
        xi, yi, xj, yj = verts[i, a], verts[i, b], verts[j, a], verts[j, b]
        if yi == yj:
            continue
        if (yi > y) != (yj > y) and x < xi + (y - yi) * (xj - xi) / (yj - yi):
            inside = not inside
    return inside


@jit
def _covers(
    kind: int,
    p: np.ndarray,
    verts: np.ndarray,
    v0: int,
    v1: int,
    face: np.ndarray,
    mr: float,
    px: float,
    py: float,
    pz: float,
) -> bool:
    """Whether the voxel centre (px, py, pz) lies inside the primitive, every part of it at
    least mr thick (docs/3d.md, "Growing into a volume")."""
    if kind == SEG3:
        r = _max(abs(p[6]) / 2.0, mr)
        return _in_segment(p[0], p[1], p[2], p[3], p[4], p[5], r * r, px, py, pz)
    if kind == SPHERE:
        dx, dy, dz = px - p[0], py - p[1], pz - p[2]
        r = _max(abs(p[3]), mr)
        hit: bool = dx * dx + dy * dy + dz * dz < r * r
        return hit
    if kind == LEAF3:
        return _in_leaf(p, mr, px, py, pz)
    return _in_poly(verts, v0, v1, face, mr, px, py, pz)


@jit
def draw(
    vox: np.ndarray,
    pyr: np.ndarray,
    pstart: np.ndarray,
    idx: np.ndarray,
    kinds: np.ndarray,
    par: np.ndarray,
    verts: np.ndarray,
    vstart: np.ndarray,
    grid: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Voxelize primitive k (kinds[k], par[k], polygon vertices verts[vstart[k]:vstart[k+1]])
    into canvas idx[k] of vox (N, nx, ny, nz) uint8 and count its new voxels into the
    pyramid rows pyr (N, P) uint16 (P == 0: no pyramid; level lv starts at pstart[lv]).
    grid = (lo x, lo y, lo z, voxel, least radius). Returns the world boxes (n, 6) and the
    new voxels as (batch row, flat voxel index (ix * ny + iy) * nz + iz), in drawing
    order."""
    n = idx.shape[0]
    shape = np.array([vox.shape[1], vox.shape[2], vox.shape[3]], dtype=np.int64)
    ny, nz = shape[1], shape[2]
    bbox = np.empty((n, 6))
    hit_k = np.empty(256, dtype=np.int64)
    hit_vox = np.empty(256, dtype=np.int64)
    m = 0
    pyramid = pyr.shape[1] > 0
    lo_x, lo_y, lo_z, size, mr = grid[0], grid[1], grid[2], grid[3], grid[4]
    for k in range(n):
        pi, kind, v0, v1 = idx[k], kinds[k], vstart[k], vstart[k + 1]
        if not 0 <= pi < vox.shape[0]:
            raise IndexError("draw: particle index out of range")
        _box(kind, par[k], verts, v0, v1, bbox[k])
        face = _face(verts, v0, v1) if kind == POLY3 else np.zeros(4)
        span = _range(bbox[k], grid, 2.0 * mr if kind == LEAF3 else mr, shape)
        # a segment's and a sphere's test inlined on scalars (as _covers: same arithmetic)
        p = par[k]
        c0, c1, c2, c3, c4, c5 = p[0], p[1], p[2], p[3], p[4], p[5]
        rr = _max(abs(p[6]) / 2.0, mr) if kind == SEG3 else _max(abs(p[3]), mr)
        r2 = rr * rr
        for i in range(span[0, 0], span[0, 1] + 1):
            px = lo_x + (i + 0.5) * size
            for j in range(span[1, 0], span[1, 1] + 1):
                py = lo_y + (j + 0.5) * size
                for q in range(span[2, 0], span[2, 1] + 1):
                    if vox[pi, i, j, q] != 0:
                        continue
                    pz = lo_z + (q + 0.5) * size
                    if kind == SPHERE:
                        dx, dy, dz = px - c0, py - c1, pz - c2
                        inside = dx * dx + dy * dy + dz * dz < r2
                    elif kind == SEG3:
                        inside = _in_segment(c0, c1, c2, c3, c4, c5, r2, px, py, pz)
                    else:
                        inside = _covers(kind, p, verts, v0, v1, face, mr, px, py, pz)
                    if not inside:
                        continue
                    vox[pi, i, j, q] = 1
                    if m == hit_k.shape[0]:
                        hit_k = np.concatenate((hit_k, np.empty(m, dtype=np.int64)))
                        hit_vox = np.concatenate((hit_vox, np.empty(m, dtype=np.int64)))
                    hit_k[m] = k
                    hit_vox[m] = (i * ny + j) * nz + q
                    m += 1
                    if pyramid:
                        for lv in range(1, N_LEVELS):
                            a, b, c = i >> lv, j >> lv, q >> lv
                            sy, sz = ny >> lv, nz >> lv
                            if a < (shape[0] >> lv) and b < sy and c < sz:
                                pyr[pi, pstart[lv] + (a * sy + b) * sz + c] += 1
    return bbox, hit_k[:m].copy(), hit_vox[:m].copy()


@jit
def _bounds(b: np.ndarray, box: np.ndarray) -> float:
    """The bounds term of one world box (xmin, ymin, zmin, xmax, ymax, zmax) against the
    program's box (xmin, xmax, ymin, ymax, zmin, zmax): minus the squared overhang per
    axis over the box's extent / BOUNDS_SCALE."""
    value = 0.0
    for a in range(3):
        if not b[0] <= b[3]:
            e = 0.0
        else:
            e = _max(box[2 * a] - b[a], 0.0) + _max(b[3 + a] - box[2 * a + 1], 0.0)
        e = e / (box[2 * a + 1] - box[2 * a])
        value -= (e / BOUNDS_SCALE) ** 2
    return value


@jit
def volume_increment(
    sim: np.ndarray,
    box: np.ndarray,
    ll: np.ndarray,
    idx: np.ndarray,
    hit_k: np.ndarray,
    hit_vox: np.ndarray,
    gain: np.ndarray,
    bbox: np.ndarray,
    pbox: np.ndarray,
    sigma: float,
) -> np.ndarray:
    """VoxelLikelihood's update: per batch row k (particle idx[k]) the similarity gain of its
    new voxels (hit_k, hit_vox), its box grown by bbox[k]; the state arrays sim, box (N, 6),
    ll are updated in place; returns new ll - old ll per row (sigma: eq. 1's 0.02)."""
    n = idx.shape[0]
    dsim = np.zeros(n)
    for m in range(hit_k.shape[0]):
        dsim[hit_k[m]] += gain[hit_vox[m]]
    delta = np.empty(n)
    for k in range(n):
        i = idx[k]
        s = sim[i] + dsim[k]
        for a in range(3):
            box[i, a] = _min(box[i, a], bbox[k, a])
            box[i, 3 + a] = _max(box[i, 3 + a], bbox[k, 3 + a])
        value = -(((s - 1.0) / sigma) ** 2) + _bounds(box[i], pbox)
        delta[k] = value - ll[i]
        sim[i] = s
        ll[i] = value
    return delta


@jit
def _unit(a: float) -> float:
    """A normalized position made finite and within [-10, 10] (features' rule)."""
    if a != a:
        return -10.0
    return min(max(a, -10.0), 10.0)


@jit
def _frame_cell(
    base: float,
    o0: float,
    o1: float,
    o2: float,
    h: float,
    lft: float,
    up: float,
    scale: float,
    s: float,
) -> int:
    """One axis of the cell at o0 H + o1 L + o2 U cells from the turtle: base = the turtle's
    position scaled to [0, 1] times the level's size s on this axis, (h, lft, up) the frame's
    components on it, scale = a cell's side * s / the grid's extent; -2 or s + 1 past the
    grid's sides."""
    d = o0 * h + o1 * lft
    v = base + (d + o2 * up) * scale
    if v != v:
        v = -2.0
    return int(_min(_max(math.floor(v), -2.0), s + 1.0))


@jit
def volume_features(
    out: np.ndarray,
    turtle: np.ndarray,
    depth: np.ndarray,
    idx: np.ndarray,
    geom: np.ndarray,
    sizes: np.ndarray,
    offs: np.ndarray,
    frame: bool,
    tstart: np.ndarray,
    target: np.ndarray,
    vox: np.ndarray,
    pyr: np.ndarray,
    pstart: np.ndarray,
    extra: np.ndarray,
    n_extra: np.ndarray,
) -> None:
    """FeatureMaker3D's rows of n particles into out (n, n_common + extra's columns)
    float32: position (3), H, L, U (9), width, depth / derivation length, extra[k,
    :n_extra[k]] (module parameters and prior arguments), then the target's and the
    canvas's windows (offsets offs (K, 3)) at the levels sizes (L, 3), then zeros. With `frame`
    an offset (a, b, c) reads the cell a H + b L + c U cells away (_frame_cell).

    turtle (n, 13): x, y, z, H, L, U, width; geom = (lo x, lo y, lo z, extent x, y, z,
    derivation length); target: its levels one after another (level lv at tstart[lv];
    empty: no target, its cells read 0); vox (N, nx, ny, nz) and pyr (N, P) the canvases
    and their count pyramids (vox with no particles: no canvas, cells read 0). Cells
    outside the grid read -1.

    Long because the frame window's per-level terms are computed here once, not per cell
    (_frame_cell takes scalars: the hot loop makes no array views)."""
    n = idx.shape[0]
    nl, nk = 14, offs.shape[0]
    nw = nk * sizes.shape[0]
    have_t, have_c = target.shape[0] > 0, vox.shape[0] > 0
    u = np.empty(3)
    cell = np.empty(3, dtype=np.int64)
    lvs, lvb, lvu = np.empty(3), np.empty(3), np.empty(3)
    for k in range(n):
        t = turtle[k]
        for a in range(3):
            u[a] = (turtle[k, a] - geom[a]) / geom[3 + a]
            out[k, a] = u[a] * 2.0 + -1.0
        for a in range(3, 13):
            out[k, a] = turtle[k, a]
        out[k, 13] = depth[k] / geom[6]
        if have_c and not 0 <= idx[k] < vox.shape[0]:
            raise IndexError("features: particle index out of range")
        e = n_extra[k]
        if not 0 <= e <= extra.shape[1] or nl + e + 2 * nw > out.shape[1]:
            raise IndexError("features: extra columns out of range")
        for a in range(e):
            out[k, nl + a] = extra[k, a]
        for a in range(nl + e + 2 * nw, out.shape[1]):
            out[k, a] = 0.0
        for a in range(3):
            if not math.isfinite(u[a]):
                u[a] = _unit(u[a])
        for lv in range(sizes.shape[0]):
            sx, sy, sz = sizes[lv, 0], sizes[lv, 1], sizes[lv, 2]
            for a in range(3):
                s = float(sizes[lv, a])
                cell[a] = int(_min(_max(math.floor(u[a] * s), -2.0), s + 1.0))
            scale = np.float32(1.0 / 8.0**lv)
            side = geom[3] / sizes[lv, 0]  # a cell's x side, world units
            for a in range(3):  # _frame_cell's per-level terms
                s = float(sizes[lv, a])
                lvs[a], lvb[a], lvu[a] = s, u[a] * s, side * s / geom[3 + a]
            for q in range(nk):
                if frame:
                    o0, o1, o2 = offs[q, 0], offs[q, 1], offs[q, 2]
                    i = _frame_cell(lvb[0], o0, o1, o2, t[3], t[6], t[9], lvu[0], lvs[0])
                    j = _frame_cell(lvb[1], o0, o1, o2, t[4], t[7], t[10], lvu[1], lvs[1])
                    c = _frame_cell(lvb[2], o0, o1, o2, t[5], t[8], t[11], lvu[2], lvs[2])
                else:
                    i, j, c = cell[0] + offs[q, 0], cell[1] + offs[q, 1], cell[2] + offs[q, 2]
                col = nl + e + nk * lv + q
                if not (0 <= i < sx and 0 <= j < sy and 0 <= c < sz):
                    out[k, col] = -1.0 if have_t else 0.0
                    out[k, col + nw] = -1.0 if have_c else 0.0
                    continue
                flat = (i * sy + j) * sz + c
                out[k, col] = target[tstart[lv] + flat] if have_t else 0.0
                if not have_c:
                    out[k, col + nw] = 0.0
                elif lv == 0:
                    out[k, col + nw] = vox[idx[k], i, j, c]
                else:
                    out[k, col + nw] = np.float32(pyr[idx[k], pstart[lv] + flat]) * scale
