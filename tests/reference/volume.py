"""Numpy versions of the compiled 3D kernels (ngpm_runtime/volume/kernels.py), the tests'
reference: voxel drawing (one vectorized coverage test per primitive over its window),
count pyramids from scratch, the voxel likelihood's increments and the 3D feature rows, with
the kernels' arithmetic in the same order, so the results are identical."""

from __future__ import annotations

import math

import numpy as np
from ngpm_runtime.geometry.turtle import Prim
from ngpm_runtime.volume.features import FRAME_WINDOWS, N_LOCAL_BASE
from ngpm_runtime.volume.kernels import BOUNDS_SCALE, EPS
from ngpm_runtime.volume.raster import MIN_RADIUS, N_LEVELS, VoxelGrid, volume_pyramid


def prim_box(p: Prim) -> np.ndarray:
    """(xmin, ymin, zmin, xmax, ymax, zmax), NaN-propagating."""
    kind = p[0]
    if kind == "seg3":
        a, b, r = np.array(p[1:4], float), np.array(p[4:7], float), abs(p[7]) / 2.0
        return np.concatenate([np.minimum(a, b) - r, np.maximum(a, b) + r])
    if kind == "sphere":
        c, r = np.array(p[1:4], float), abs(p[4])
        return np.concatenate([c - r, c + r])
    if kind == "leaf3":
        pos, h, lv = (np.array(p[i : i + 3], float) for i in (1, 4, 7))
        ha, hb = p[10] / 2.0, abs(p[11]) / 2.0
        c = pos + ha * h
        e = np.sqrt((ha * h) ** 2 + (hb * lv) ** 2)
        return np.concatenate([c - e, c + e])
    v = np.asarray(p[1], float).reshape(-1, 3)
    if len(v) == 0:
        return np.array([np.inf] * 3 + [-np.inf] * 3)
    lo, hi = v[0].copy(), v[0].copy()
    for row in v[1:]:
        lo, hi = np.minimum(lo, row), np.maximum(hi, row)
    return np.concatenate([lo, hi])


def voxel_range(box: np.ndarray, grid: VoxelGrid, reach: float) -> list[tuple[int, int]]:
    """First and last voxel per axis whose centre may be covered."""
    out = []
    for a in range(3):
        lo = (box[a] - reach - grid.lo[a]) / grid.voxel - 0.5 - EPS
        hi = (box[3 + a] + reach - grid.lo[a]) / grid.voxel - 0.5 + EPS
        if not (math.isfinite(lo) and math.isfinite(hi)):
            out.append((0, -1))
            continue
        n = grid.shape[a]
        lo, hi = min(max(lo, -1.0), n + 1.0), min(max(hi, -2.0), n + 1.0)
        out.append((max(math.ceil(lo), 0), min(math.floor(hi), n - 1)))
    return out


def _segment(a, b, r2, px, py, pz):
    ex, ey, ez = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    l2 = ex * ex + ey * ey + ez * ez
    inv = 1.0 / l2 if l2 > 0 else 0.0
    dx, dy, dz = px - a[0], py - a[1], pz - a[2]
    t = np.clip(dx * (ex * inv) + dy * (ey * inv) + dz * (ez * inv), 0.0, 1.0)
    qx, qy, qz = dx - t * ex, dy - t * ey, dz - t * ez
    return qx * qx + qy * qy + qz * qz < r2


def _face(v: np.ndarray) -> tuple[np.ndarray, int]:
    nx = ny = nz = 0.0
    m = len(v)
    for i in range(m):
        j = (i + 1) % m
        nx += (v[i, 1] - v[j, 1]) * (v[i, 2] + v[j, 2])
        ny += (v[i, 2] - v[j, 2]) * (v[i, 0] + v[j, 0])
        nz += (v[i, 0] - v[j, 0]) * (v[i, 1] + v[j, 1])
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    if m < 3 or not (norm > 0 and math.isfinite(norm)):
        return np.zeros(3), -1
    f = np.array([nx / norm, ny / norm, nz / norm])
    ax, ay, az = np.abs(f)
    return f, (0 if (ax >= ay and ax >= az) else (1 if ay >= az else 2))


def _poly(v, mr, px, py, pz):
    m = len(v)
    hit = np.zeros(np.broadcast(px, py, pz).shape, dtype=bool)
    for i in range(m):
        hit |= _segment(v[i], v[(i + 1) % m], mr * mr, px, py, pz)
    f, drop = _face(v)
    if drop < 0:
        return hit
    d = (px - v[0, 0]) * f[0] + (py - v[0, 1]) * f[1] + (pz - v[0, 2]) * f[2]
    a, b = ((1, 2), (2, 0), (0, 1))[drop]
    pts = np.broadcast_arrays(px, py, pz)
    x, y = pts[a], pts[b]
    inside = np.zeros(x.shape, dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(m):
            j = i - 1 if i > 0 else m - 1
            xi, yi, xj, yj = v[i, a], v[i, b], v[j, a], v[j, b]
            if yi == yj:
                continue
            inside ^= ((yi > y) != (yj > y)) & (x < xi + (y - yi) * (xj - xi) / (yj - yi))
    return hit | ((d * d < mr * mr) & inside)


def covers(p: Prim, mr: float, px, py, pz) -> np.ndarray:
    """Coverage of voxel centres (broadcast px, py, pz) by one primitive."""
    kind = p[0]
    if kind == "seg3":
        r = max(abs(p[7]) / 2.0, mr)
        return _segment(p[1:4], p[4:7], r * r, px, py, pz)
    if kind == "sphere":
        dx, dy, dz = px - p[1], py - p[2], pz - p[3]
        r = max(abs(p[4]), mr)
        return dx * dx + dy * dy + dz * dz < r * r
    if kind == "leaf3":
        q = p[1:12]
        ha = q[9] / 2.0
        a, b = max(abs(ha), mr), max(abs(q[10]) / 2.0, mr)
        dx, dy, dz = px - (q[0] + ha * q[3]), py - (q[1] + ha * q[4]), pz - (q[2] + ha * q[5])
        nx = q[4] * q[8] - q[5] * q[7]
        ny = q[5] * q[6] - q[3] * q[8]
        nz = q[3] * q[7] - q[4] * q[6]
        n = dx * nx + dy * ny + dz * nz
        u = dx * q[3] + dy * q[4] + dz * q[5]
        v = dx * q[6] + dy * q[7] + dz * q[8]
        return (n * n < mr * mr) & (u * u * (b * b) + v * v * (a * a) < (a * a) * (b * b))
    return _poly(np.asarray(p[1], float).reshape(-1, 3), mr, px, py, pz)


def draw(
    voxels: np.ndarray, grid: VoxelGrid, idx: np.ndarray, prims: list[Prim]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw prims[k] into voxels[idx[k]] in turn; (boxes, hit rows, flat voxel indices)."""
    mr = MIN_RADIUS * grid.voxel
    _, ny, nz = grid.shape
    boxes, ks, vs = [], [], []
    for k, (i, p) in enumerate(zip(idx, prims, strict=True)):
        box = prim_box(p)
        boxes.append(box)
        (x0, x1), (y0, y1), (z0, z1) = voxel_range(box, grid, (2 if p[0] == "leaf3" else 1) * mr)
        if x1 < x0 or y1 < y0 or z1 < z0:
            continue
        px = (grid.lo[0] + (np.arange(x0, x1 + 1) + 0.5) * grid.voxel)[:, None, None]
        py = (grid.lo[1] + (np.arange(y0, y1 + 1) + 0.5) * grid.voxel)[None, :, None]
        pz = (grid.lo[2] + (np.arange(z0, z1 + 1) + 0.5) * grid.voxel)[None, None, :]
        window = voxels[i, x0 : x1 + 1, y0 : y1 + 1, z0 : z1 + 1]
        with np.errstate(invalid="ignore", over="ignore"):
            new = covers(p, mr, px, py, pz) & (window == 0)
        window[new] = 1
        a, b, c = np.nonzero(new)
        ks.append(np.full(len(a), k))
        vs.append(((a + x0) * ny + b + y0) * nz + c + z0)
    empty = np.zeros(0, dtype=np.int64)
    return (
        np.array(boxes).reshape(-1, 6),
        np.concatenate(ks) if ks else empty,
        np.concatenate(vs) if vs else empty,
    )


def count_row(voxels: np.ndarray) -> np.ndarray:
    """One canvas's count pyramid (levels 1-3, row-major, one after another) from scratch."""
    out = []
    g = voxels.astype(np.int64)
    for lv in range(1, N_LEVELS):
        s = 1 << lv
        x, y, z = (n >> lv for n in g.shape)
        c = g[: x * s, : y * s, : z * s].reshape(x, s, y, s, z, s).sum(axis=(1, 3, 5))
        out.append(c.reshape(-1))
    return np.concatenate(out).astype(np.uint16)


def bounds(b: np.ndarray, box: tuple[float, ...]) -> float:
    value = 0.0
    for a in range(3):
        e = (
            0.0
            if not b[0] <= b[3]
            else max(box[2 * a] - b[a], 0.0) + max(b[3 + a] - box[2 * a + 1], 0.0)
        )
        e = e / (box[2 * a + 1] - box[2 * a])
        value -= (e / BOUNDS_SCALE) ** 2
    return value


def increment(state, like, idx, bbox, hit_k, hit_vox) -> np.ndarray:
    """VoxelLikelihood.increment in numpy (state arrays updated in place)."""
    dsim = np.zeros(len(idx))
    np.add.at(dsim, hit_k, like.gain[hit_vox])
    delta = np.empty(len(idx))
    for k, i in enumerate(idx):
        s = state["sim"][i] + dsim[k]
        box = state["bbox"][i]
        box[:3] = np.minimum(box[:3], bbox[k, :3])
        box[3:] = np.maximum(box[3:], bbox[k, 3:])
        value = -(((s - 1.0) / like.sigma) ** 2) + bounds(box, like.box)
        delta[k] = value - state["ll"][i]
        state["sim"][i], state["ll"][i] = s, value
    return delta


def _unit(a: float) -> float:
    return -10.0 if a != a else min(max(a, -10.0), 10.0)


def _frame_cell(base, o, t, a, scale, size) -> int:
    """The cell along axis a of the point o[0] H + o[1] L + o[2] U cells from `base`."""
    v = base + (o[0] * t[3 + a] + o[1] * t[6 + a] + o[2] * t[9 + a]) * scale
    v = -2.0 if v != v else v
    return int(min(max(math.floor(v), -2.0), size + 1.0))


def feature_rows(fm, voxels, turtles, depths, target_occupancy) -> np.ndarray:
    """FeatureMaker3D's common columns of particles with canvases `voxels` (n, ...) from
    scratch (no canvas: None)."""
    grid, offs = fm.grid, fm.offs
    ext = np.array(grid.shape, float) * grid.voxel
    tl = None if target_occupancy is None else volume_pyramid(target_occupancy)
    out = np.empty((len(turtles), fm.n_common), dtype=np.float32)
    nw = len(offs) * N_LEVELS
    for k, t in enumerate(turtles):
        u = [(t[a] - grid.lo[a]) / ext[a] for a in range(3)]
        out[k, :3] = [x * 2.0 + -1.0 for x in u]
        out[k, 3:13] = t[3:13]
        out[k, 13] = depths[k] / fm.derivation_length
        u = [x if math.isfinite(x) else _unit(x) for x in u]
        cl = None if voxels is None else volume_pyramid(voxels[k])
        for lv in range(N_LEVELS):
            size = [n >> lv for n in grid.shape]
            cell = [
                int(min(max(math.floor(u[a] * size[a]), -2.0), size[a] + 1.0)) for a in range(3)
            ]
            side = ext[0] / size[0]
            for q, o in enumerate(offs):
                at = tuple(cell[a] + o[a] for a in range(3))
                if fm.window in FRAME_WINDOWS:  # o[0] H + o[1] L + o[2] U, in cells
                    at = tuple(
                        _frame_cell(u[a] * size[a], o, t, a, side * size[a] / ext[a], size[a])
                        for a in range(3)
                    )
                inside = all(0 <= at[a] < size[a] for a in range(3))
                col = N_LOCAL_BASE + len(offs) * lv + q
                out[k, col] = 0.0 if tl is None else (tl[lv][at] if inside else -1.0)
                out[k, col + nw] = 0.0 if cl is None else (cl[lv][at] if inside else -1.0)
    return out
