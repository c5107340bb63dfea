"""Compiled numeric kernels of the SMC step (numba), each over a whole population.

One call per step and part: `draw` (primitives -> canvases and their count pyramids),
`shape_increment` / `circuit_increment` (the likelihoods' incremental updates),
`unpack_round` (a guided round's particle state into the rows of the next two),
`feature_windows` (turtle columns, 3x3 windows at 4 levels, context), `guide_round` (site
networks, draws, log q, log prior), `add_weights` (SMC's site weights), `residual_counts`,
`ancestors` and `take_rows` (resampling). They do the arithmetic of the numpy code they
replaced (tests/reference/ keeps it) in the same order, so images, pyramids, likelihoods,
features and ancestors are bit-identical to it (sums included: `_pairwise_sum` adds as
numpy's sum does).

numba compiles each kernel on first use and caches it on disk (`cache=True`: in
`__pycache__` beside this file, or numba's user cache when that is not writable). This
module is imported lazily (by the Canvas, FeatureMaker, likelihoods and resampling) so that
importing the runtime, and `ngpmc --help`, does not load numba.
"""

from __future__ import annotations

import importlib
import math
import sys

import numpy as np
from numba import njit


def _load_array_typing() -> None:
    """Import numba's array typing (numba.np.arraymath) with scipy.linalg hidden, if it is
    not loaded yet: the module probes scipy's BLAS on import, which costs 0.3-0.4 s of scipy
    imports at the first kernel call. The kernels use no BLAS; the probe's only effect is
    that np.vdot in numba code of this process uses a plain loop."""
    hide = "scipy.linalg" not in sys.modules
    if hide:
        sys.modules["scipy.linalg"] = None  # type: ignore[assignment]  # its import fails
    try:
        importlib.import_module("numba.np.arraymath")
    finally:
        if hide:
            del sys.modules["scipy.linalg"]


_load_array_typing()

PAD = 3  # as raster.PAD (raster imports this module lazily, so the value is repeated)
N_LEVELS = 4
EPS = 1e-9
SEG, DISK, LEAF, POLY = 0, 1, 2, 3  # primitive kind codes of `draw`
SHAPE_SIGMA = 0.02  # as likelihood.py
BOUNDS_SCALE = 0.001
CIRCUIT_TAU = 0.5
CIRCUIT_SIGMA = 0.01
CIRCUIT_LOG_NORM = math.log(CIRCUIT_SIGMA * math.sqrt(2.0 * math.pi))
# every kernel: cached on disk, releases the GIL, numpy's float semantics (x / 0 -> inf)
jit = njit(cache=True, nogil=True, error_model="numpy")
# Sobel magnitude / 4 of a 0/1 image by its integer gradients (gx + 4) * 9 + (gy + 4)
_GRAD = np.arange(-4, 5)
MAG_LUT = (np.sqrt(_GRAD[:, None] ** 2 + _GRAD[None, :] ** 2) / 4.0).reshape(-1)
# feature_windows' memo arguments for no memo
NO_MEMO = np.zeros((0, 0), dtype=np.float32)
NO_MEMO_KEY = np.zeros((0, 3))


@jit
def _min(a: float, b: float) -> float:
    """np.minimum of two floats (a NaN wins)."""
    return a if (a <= b or a != a) else b


@jit
def _max(a: float, b: float) -> float:
    """np.maximum of two floats (a NaN wins)."""
    return a if (a >= b or a != a) else b


@jit
def _prim_box(
    kind: int, p: np.ndarray, verts: np.ndarray, v0: int, v1: int, out: np.ndarray
) -> None:
    """World box (xmin, ymin, xmax, ymax) of one primitive, as turtle.prim_bboxes."""
    if kind == SEG:
        r = abs(p[4]) / 2.0
        out[0] = _min(p[0], p[2]) - r
        out[1] = _min(p[1], p[3]) - r
        out[2] = _max(p[0], p[2]) + r
        out[3] = _max(p[1], p[3]) + r
    elif kind == DISK:
        r = abs(p[2])
        out[0], out[1], out[2], out[3] = p[0] - r, p[1] - r, p[0] + r, p[1] + r
    elif kind == LEAF:
        rad = np.radians(p[2])
        c, s = math.cos(rad), math.sin(rad)
        a, b = abs(p[3]) / 2.0, abs(p[4]) / 2.0
        cx, cy = p[0] + p[3] / 2.0 * c, p[1] + p[3] / 2.0 * s
        ex = math.sqrt((a * c) ** 2 + (b * s) ** 2)
        ey = math.sqrt((a * s) ** 2 + (b * c) ** 2)
        out[0], out[1], out[2], out[3] = cx - ex, cy - ey, cx + ex, cy + ey
    else:
        out[0], out[1], out[2], out[3] = np.inf, np.inf, -np.inf, -np.inf
        for v in range(v0, v1):
            if v == v0:
                out[0], out[1], out[2], out[3] = verts[v, 0], verts[v, 1], verts[v, 0], verts[v, 1]
            else:
                out[0] = _min(out[0], verts[v, 0])
                out[1] = _min(out[1], verts[v, 1])
                out[2] = _max(out[2], verts[v, 0])
                out[3] = _max(out[3], verts[v, 1])


@jit
def _windows(
    bbox: np.ndarray, view: np.ndarray, h: int, w: int
) -> tuple[np.ndarray, np.ndarray, int, int, np.ndarray]:
    """Common window (ky, kx), origins y0, x0 and empty flags of the boxes (raster's rule:
    pixel centres inside each box, clipped to the image)."""
    n = bbox.shape[0]
    xmin, ymax, sx, sy = view[0], view[1], view[2], view[3]
    lo = np.empty((n, 2), dtype=np.int64)  # (x, y) pixel corners
    hi = np.empty((n, 2), dtype=np.int64)
    empty = np.zeros(n, dtype=np.bool_)
    kx, ky = -1, -1
    for k in range(n):
        finite = True
        for q in range(4):
            if not math.isfinite(bbox[k, q]):
                finite = False
        if not finite:
            empty[k] = True
            lo[k, 0], lo[k, 1] = 0, 0
            continue
        corners = (
            (bbox[k, 0] - xmin) / sx - 0.5,
            (bbox[k, 3] - ymax) / -sy - 0.5,
            (bbox[k, 2] - xmin) / sx - 0.5,
            (bbox[k, 1] - ymax) / -sy - 0.5,
        )
        lims = (w + 1.0, h + 1.0, w + 1.0, h + 1.0)
        lasts = (0.0, 0.0, w - 1.0, h - 1.0)
        for q in range(4):
            v = corners[q] - EPS if q < 2 else corners[q] + EPS
            v = _min(_max(v, -1.0), lims[q])
            if q < 2:
                lo[k, q] = int(_max(math.ceil(v), lasts[q]))
            else:
                hi[k, q - 2] = int(_min(math.floor(v), lasts[q]))
        if hi[k, 0] < lo[k, 0] or hi[k, 1] < lo[k, 1]:
            empty[k] = True
        else:
            kx = max(kx, hi[k, 0] - lo[k, 0] + 1)
            ky = max(ky, hi[k, 1] - lo[k, 1] + 1)
    if kx < 0:
        kx, ky = 1, 1
    kx, ky = min(max(1, kx), w), min(max(1, ky), h)
    y0 = np.zeros(n, dtype=np.int64)
    x0 = np.zeros(n, dtype=np.int64)
    for k in range(n):
        if not empty[k]:
            x0[k] = min(lo[k, 0], w - kx)
            y0[k] = min(lo[k, 1], h - ky)
    return y0, x0, ky, kx, empty


@jit
def _covers(
    kind: int, p: np.ndarray, verts: np.ndarray, v0: int, v1: int, x: float, y: float
) -> bool:
    """Whether the pixel centre (x, y) lies strictly inside the primitive (raster's tests,
    operation for operation)."""
    if kind == SEG:
        ex, ey = p[2] - p[0], p[3] - p[1]
        l2 = ex * ex + ey * ey
        inv = 1.0 / l2 if l2 > 0 else 0.0
        dx, dy = x - p[0], y - p[1]
        t = dx * (ex * inv) + dy * (ey * inv)
        if t < 0.0:
            t = 0.0
        if t > 1.0:
            t = 1.0
        qx = dx - t * ex
        qy = dy - t * ey
        hit: bool = qx * qx + qy * qy < (p[4] * p[4]) / 4.0
        return hit
    if kind == DISK:
        dx, dy = x - p[0], y - p[1]
        hit = dx * dx + dy * dy < p[2] * p[2]
        return hit
    if kind == LEAF:
        rad = np.radians(p[2])
        c, s = math.cos(rad), math.sin(rad)
        a, b = abs(p[3]) / 2.0, abs(p[4]) / 2.0
        dx, dy = x - (p[0] + p[3] / 2.0 * c), y - (p[1] + p[3] / 2.0 * s)
        u = dx * (c * b) + dy * (s * b)
        v = dy * (c * a) - dx * (s * a)
        hit = u * u + v * v < (a * b) ** 2
        return hit
    inside = False
    if v1 - v0 < 3:
        return inside
    for i in range(v0, v1):
        j = i - 1 if i > v0 else v1 - 1
        xi, yi, xj, yj = verts[i, 0], verts[i, 1], verts[j, 0], verts[j, 1]
        if yi == yj:
            continue  # horizontal edges never cross a horizontal ray
        if (yi > y) != (yj > y) and x < xi + (y - yi) * (xj - xi) / (yj - yi):
            inside = not inside
    return inside


@jit
def draw(
    image: np.ndarray,
    padded: np.ndarray,
    idx: np.ndarray,
    kinds: np.ndarray,
    par: np.ndarray,
    verts: np.ndarray,
    vstart: np.ndarray,
    view: np.ndarray,
    wp: np.ndarray,
    starts: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rasterize primitive k (kinds[k], par[k], polygon vertices verts[vstart[k]:vstart[k+1]])
    into canvas idx[k] of image (N, H, W) uint8, and its new pixels into the padded pyramid
    rows (N, T) float32 (T == 0: no pyramid). view = (xmin, ymax, sx, sy); wp, starts: the
    padded layout. Returns bbox (n, 4), y0, x0 (n,), new (n, ky, kx) bool and the new
    pixels as (batch row, row * W + col) in row-major order.

    Long because segments', disks' and leaves' pixel tests are inlined, their
    per-primitive terms computed once: `_covers` called per pixel took 2-3x as long."""
    n = idx.shape[0]
    h, w = image.shape[1], image.shape[2]
    bbox = np.empty((n, 4))
    for k in range(n):
        if not 0 <= idx[k] < image.shape[0]:
            raise IndexError("draw: particle index out of range")
        _prim_box(kinds[k], par[k], verts, vstart[k], vstart[k + 1], bbox[k])
    y0, x0, ky, kx, empty = _windows(bbox, view, h, w)
    new = np.zeros((n, ky, kx), dtype=np.bool_)
    hit_k = np.empty(n * ky * kx, dtype=np.int64)
    hit_pix = np.empty(n * ky * kx, dtype=np.int64)
    m = 0
    pyr = padded.shape[1] > 0
    xmin, ymax, sx, sy = view[0], view[1], view[2], view[3]
    for k in range(n):
        if empty[k]:
            continue
        pi, kind, v0, v1 = idx[k], kinds[k], vstart[k], vstart[k + 1]
        # segments', disks' and leaves' tests inlined, their per-primitive terms hoisted
        # (as _covers, operation for operation)
        p = par[k]
        ex, ey = p[2] - p[0], p[3] - p[1]
        l2 = ex * ex + ey * ey
        inv = 1.0 / l2 if l2 > 0 else 0.0
        exi, eyi = ex * inv, ey * inv
        seg_r2 = (p[4] * p[4]) / 4.0
        disk_r2 = p[2] * p[2]
        rad = np.radians(p[2])
        lc, ls = math.cos(rad), math.sin(rad)
        la, lb = abs(p[3]) / 2.0, abs(p[4]) / 2.0
        lx, ly = p[0] + p[3] / 2.0 * lc, p[1] + p[3] / 2.0 * ls
        lcb, lsb, lca, lsa, lab2 = lc * lb, ls * lb, lc * la, ls * la, (la * lb) ** 2
        for i in range(ky):
            r = y0[k] + i
            y = ymax - (r + 0.5) * sy
            for j in range(kx):
                c = x0[k] + j
                if image[pi, r, c] != 0:
                    continue
                x = xmin + (c + 0.5) * sx
                if kind == SEG:
                    dx, dy = x - p[0], y - p[1]
                    t = dx * exi + dy * eyi
                    t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
                    qx, qy = dx - t * ex, dy - t * ey
                    inside = qx * qx + qy * qy < seg_r2
                elif kind == DISK:
                    dx, dy = x - p[0], y - p[1]
                    inside = dx * dx + dy * dy < disk_r2
                elif kind == LEAF:
                    dx, dy = x - lx, y - ly
                    u = dx * lcb + dy * lsb
                    v = dy * lca - dx * lsa
                    inside = u * u + v * v < lab2
                else:
                    inside = _covers(kind, p, verts, v0, v1, x, y)
                if not inside:
                    continue
                new[k, i, j] = True
                image[pi, r, c] = 1
                hit_k[m] = k
                hit_pix[m] = r * w + c
                m += 1
                if pyr:
                    padded[pi, starts[0] + (r + PAD) * wp[0] + c + PAD] = 1.0
                    for lv in range(1, N_LEVELS):
                        rl, cl = r >> lv, c >> lv
                        if rl < (h >> lv) and cl < (w >> lv):
                            padded[pi, starts[lv] + (rl + PAD) * wp[lv] + cl + PAD] += np.float32(
                                1.0 / 4.0**lv
                            )
    return bbox, y0, x0, new, hit_k[:m], hit_pix[:m]


@jit
def _bounds(b: np.ndarray, vp: np.ndarray) -> float:
    """likelihood.bounds_penalty of one box (xmin, ymin, xmax, ymax); vp (xmin, xmax, ymin,
    ymax)."""
    if not b[0] <= b[2]:
        ex, ey = 0.0, 0.0
    else:
        ex = _max(vp[0] - b[0], 0.0) + _max(b[2] - vp[1], 0.0)
        ey = _max(vp[2] - b[1], 0.0) + _max(b[3] - vp[3], 0.0)
    ex = ex / (vp[1] - vp[0])
    ey = ey / (vp[3] - vp[2])
    value: float = -((ex / BOUNDS_SCALE) ** 2) - (ey / BOUNDS_SCALE) ** 2
    return value


@jit
def _union(state: np.ndarray, b: np.ndarray) -> None:
    """state |= b for boxes (xmin, ymin, xmax, ymax), NaN-propagating like np.minimum."""
    state[0] = _min(state[0], b[0])
    state[1] = _min(state[1], b[1])
    state[2] = _max(state[2], b[2])
    state[3] = _max(state[3], b[3])


@jit
def shape_increment(
    sim: np.ndarray,
    box: np.ndarray,
    ll: np.ndarray,
    idx: np.ndarray,
    hit_k: np.ndarray,
    hit_pix: np.ndarray,
    gain: np.ndarray,
    bbox: np.ndarray,
    vp: np.ndarray,
) -> np.ndarray:
    """ShapeLikelihood's update: per batch row k (particle idx[k]) the similarity gain of its
    new pixels (hit_k, hit_pix), the box grown by bbox[k]; the state arrays sim, box, ll
    (per particle) are updated in place; returns new ll - old ll per row."""
    n = idx.shape[0]
    dsim = np.zeros(n)
    for m in range(hit_k.shape[0]):
        dsim[hit_k[m]] += gain[hit_pix[m]]
    delta = np.empty(n)
    for k in range(n):
        i = idx[k]
        s = sim[i] + dsim[k]
        _union(box[i], bbox[k])
        value = -(((s - 1.0) / SHAPE_SIGMA) ** 2) + _bounds(box[i], vp)
        delta[k] = value - ll[i]
        sim[i] = s
        ll[i] = value
    return delta


@jit
def _sobel_code(
    image: np.ndarray,
    p: int,
    r: int,
    c: int,
    new: np.ndarray,
    k: int,
    y0: int,
    x0: int,
    before: bool,
) -> int:
    """MAG_LUT code of the Sobel gradient at (r, c) of canvas p (zero outside); `before`:
    without the batch row k's new pixels."""
    h, w = image.shape[1], image.shape[2]
    ky, kx = new.shape[1], new.shape[2]
    gx, gy = 0, 0
    for di in range(-1, 2):
        for dj in range(-1, 2):
            rr, cc = r + di, c + dj
            if rr < 0 or rr >= h or cc < 0 or cc >= w:
                continue
            v = int(image[p, rr, cc])
            if before and 0 <= rr - y0 < ky and 0 <= cc - x0 < kx and new[k, rr - y0, cc - x0]:
                v = 0
            gx += dj * (2 - abs(di)) * v  # columns' difference, rows smoothed 1, 2, 1
            gy += di * (2 - abs(dj)) * v
    return (gx + 4) * 9 + (gy + 4)


@jit
def circuit_increment(
    edge_sum: np.ndarray,
    filled: np.ndarray,
    box: np.ndarray,
    ll: np.ndarray,
    pot: np.ndarray,
    image: np.ndarray,
    idx: np.ndarray,
    y0: np.ndarray,
    x0: np.ndarray,
    new: np.ndarray,
    bbox: np.ndarray,
    vp: np.ndarray,
) -> np.ndarray:
    """CircuitLikelihood's update (image already drawn): the change of each canvas's Sobel
    sum over its window and a 1-pixel ring, its new pixel count, the grown box; state arrays
    updated in place: ll the log-likelihood (equation 2), pot the potential (equation 2
    with a fill below TAU not counted against it: an unfinished vine can still fill);
    returns new pot - old pot per batch row (CircuitLikelihood.settle adds ll - pot when a
    particle finishes)."""
    n = idx.shape[0]
    h, w = image.shape[1], image.shape[2]
    ky, kx = new.shape[1], new.shape[2]
    npx = float(h * w)
    delta = np.empty(n)
    buf = np.zeros((ky + 2) * (kx + 2))
    for k in range(n):
        p = idx[k]
        count = 0
        for i in range(ky):
            for j in range(kx):
                count += new[k, i, j]
        d_edge = 0.0
        if count:
            # the changes over the window and its ring, summed in numpy's order
            buf[:] = 0.0
            for r in range(max(y0[k] - 1, 0), min(y0[k] + ky + 1, h)):
                for c in range(max(x0[k] - 1, 0), min(x0[k] + kx + 1, w)):
                    buf[(r - y0[k] + 1) * (kx + 2) + c - x0[k] + 1] = (
                        MAG_LUT[_sobel_code(image, p, r, c, new, k, y0[k], x0[k], False)]
                        - MAG_LUT[_sobel_code(image, p, r, c, new, k, y0[k], x0[k], True)]
                    )
            d_edge = _pairwise_sum(buf)
        edge_sum[p] += d_edge
        filled[p] += count
        _union(box[p], bbox[k])
        edge, fill = edge_sum[p] / npx, filled[p] / npx
        bounds = _bounds(box[p], vp)
        x = edge * (1.0 - abs(fill - CIRCUIT_TAU) / CIRCUIT_TAU)
        z = (x - 1.0) / CIRCUIT_SIGMA
        ll[p] = -0.5 * z * z - CIRCUIT_LOG_NORM + bounds
        x = edge * (1.0 - max(fill - CIRCUIT_TAU, 0.0) / CIRCUIT_TAU)
        z = (x - 1.0) / CIRCUIT_SIGMA
        value = -0.5 * z * z - CIRCUIT_LOG_NORM + bounds
        delta[k] = value - pot[p]
        pot[p] = value
    return delta


@jit
def _unit(a: float) -> float:
    """A normalized position made finite and within [-10, 10] (features' rule)."""
    if a != a:
        return -10.0
    return min(max(a, -10.0), 10.0)  # +-inf -> +-10


@jit
def _memo_width(ctx: np.ndarray) -> int:
    """feature_windows' memo columns: both groups of windows, and the context group when
    there is a look-ahead (ctx)."""
    return 2 * 9 * N_LEVELS + (ctx.shape[0] + 2 if ctx.shape[0] else 0)


@jit
def _windows_row(
    out: np.ndarray,
    u: float,
    v: float,
    hd: float,
    i: int,
    view: np.ndarray,
    size: np.ndarray,
    offs: np.ndarray,
    target: np.ndarray,
    canvas: np.ndarray,
    ctx: np.ndarray,
    ctx_geom: np.ndarray,
    cells: np.ndarray,
    cell_t: np.ndarray,
) -> None:
    """feature_windows' columns after a row's extra ones (out: the row from there) for a
    turtle at normalized (u, v) heading hd, of particle i: target and partial windows at
    the 4 levels, then the context group (or zeros to the end of the row)."""
    nw = 9 * N_LEVELS
    if not (math.isfinite(u) and math.isfinite(v)):
        u, v = _unit(u), _unit(v)
    if size.shape[1] == 0:
        out[:nw] = view[5]
        out[nw : 2 * nw] = view[6]
    for lv in range(size.shape[1]):
        row = _min(_max(math.floor(v * size[0, lv]), -2.0), size[0, lv] + 1)
        col = _min(_max(math.floor(u * size[1, lv]), -2.0), size[1, lv] + 1)
        at0 = int(row * size[2, lv] + col)
        for q in range(9):
            at = at0 + offs[lv, q]
            out[9 * lv + q] = target[at] if target.shape[0] else view[5]
            out[nw + 9 * lv + q] = canvas[i, at] if canvas.shape[1] else view[6]
    if out.shape[0] > 2 * nw and not ctx.shape[0]:
        out[2 * nw :] = 0.0
    elif ctx.shape[0]:
        _context(out[2 * nw :], canvas[i], target, u, v, hd, ctx, ctx_geom, cells, cell_t)


@jit
def feature_windows(
    out: np.ndarray,
    turtle: np.ndarray,
    depth: np.ndarray,
    idx: np.ndarray,
    view: np.ndarray,
    size: np.ndarray,
    offs: np.ndarray,
    target: np.ndarray,
    canvas: np.ndarray,
    ctx: np.ndarray,
    ctx_geom: np.ndarray,
    cells: np.ndarray,
    cell_t: np.ndarray,
    extra: np.ndarray,
    n_extra: np.ndarray,
    memo: np.ndarray,
    memo_key: np.ndarray,
) -> None:
    """FeatureMaker's rows of n particles into out (n, >= 7 + e + 72 [+ 2 + R]) float32:
    turtle columns, the row's e = n_extra[k] extra columns extra[k, :e] (module parameters
    and prior arguments), target and partial 3x3 windows at the 4 levels (target (T,) and
    canvas (N, T) padded pyramids; an empty one: that group is view[5] or view[6]) and,
    when `ctx` (R look-ahead rows: angle, distance, then their level's first cell (start +
    padding), padded width, height and width) is not empty, the context group and the far
    look-ahead after it (else zeros to the end of the row).

    view = (xmin, ymax, xmax - xmin, -(ymax - ymin), derivation length, target fill, canvas
    fill); size (3, L) level heights, widths and padded widths (L == 0: no image, every
    window cell is its fill); offs (L, 9) window offsets; ctx_geom = (total, aspect): the
    target's sum on the fill level and the viewport's width / height; cells, cell_t: the
    fill level's cells and the target there.

    memo (P, 2 * 72 [+ 2 + R]) float32, memo_key (P, 3) float64, P > 0: the windows and
    context of particle i's last row (those columns depend only on the turtle's x, y and
    heading, its canvas row and the target) and that turtle, reused for a row of the same
    particle and turtle: one step's rounds, whose canvas does not change, give the same
    numbers without the work (a new canvas needs memo_key reset to NaN). P == 0: none."""
    n = idx.shape[0]
    nw = 9 * N_LEVELS
    n_ctx = _memo_width(ctx) - 2 * nw
    for k in range(n):
        u = (turtle[k, 0] - view[0]) / view[2]
        v = (turtle[k, 1] - view[1]) / view[3]
        out[k, 0] = u * 2.0 + -1.0
        out[k, 1] = v * -2.0 + 1.0
        hd = turtle[k, 2]
        out[k, 2] = (hd % 360.0) / 180.0 - 1.0  # Python's and np.mod's float rule
        rad = np.radians(hd)
        out[k, 3] = math.sin(rad)
        out[k, 4] = math.cos(rad)
        out[k, 5] = turtle[k, 3]
        out[k, 6] = depth[k] / view[4]
        e = n_extra[k]
        for q in range(e):
            out[k, 7 + q] = extra[k, q]
        nl = 7 + e
        if canvas.shape[1] and not 0 <= idx[k] < canvas.shape[0]:
            raise IndexError("features: particle index out of range")
        i = idx[k]
        if memo_key.shape[0] and (
            memo_key[i, 0] == turtle[k, 0]
            and memo_key[i, 1] == turtle[k, 1]
            and memo_key[i, 2] == hd
        ):
            out[k, nl : nl + 2 * nw + n_ctx] = memo[i, : 2 * nw + n_ctx]
            if out.shape[1] > nl + 2 * nw and not n_ctx:
                out[k, nl + 2 * nw :] = 0.0
            continue
        _windows_row(
            out[k, nl:], u, v, hd, i, view, size, offs, target, canvas, ctx, ctx_geom, cells, cell_t
        )
        if memo_key.shape[0]:
            memo[i, : 2 * nw + n_ctx] = out[k, nl : nl + 2 * nw + n_ctx]
            memo_key[i, 0], memo_key[i, 1], memo_key[i, 2] = turtle[k, 0], turtle[k, 1], hd


@jit
def _context(
    out: np.ndarray,
    row: np.ndarray,
    target: np.ndarray,
    u: float,
    v: float,
    heading: float,
    ctx: np.ndarray,
    geom: np.ndarray,
    cells: np.ndarray,
    cell_t: np.ndarray,
) -> None:
    """The context group of one particle (features.py's module docstring): fill fractions,
    then the look-ahead samples of the unfilled target."""
    total = np.float32(geom[0])
    unfilled, dsum = np.float32(0.0), np.float32(0.0)
    for q in range(cells.shape[0]):
        d = cell_t[q] - row[cells[q]]
        dsum += d
        if d > 0:
            unfilled += d
    out[0] = unfilled / total
    out[1] = (unfilled - dsum) / total
    aspect = geom[1]
    for q in range(ctx.shape[0]):
        base, wp, hl, wl = int(ctx[q, 2]), ctx[q, 3], ctx[q, 4], ctx[q, 5]
        ang = np.radians(heading + ctx[q, 0])
        r = math.floor((v - math.sin(ang) * ctx[q, 1] * aspect) * hl)
        c = math.floor((u + math.cos(ang) * ctx[q, 1]) * wl)
        r = min(max(r, -1.0), hl) if r == r else -1.0
        c = min(max(c, -1.0), wl) if c == c else -1.0
        at = int(r * wp + c) + base
        tv = target[at]
        if tv < 0:
            out[2 + q] = -1.0
        else:
            ahead = tv - row[at]
            out[2 + q] = ahead if ahead > 0 else np.float32(0.0)


@jit
def _block_sum(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's sum of a block of at most 128 floats: eight accumulators, then the rest."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r = a[lo : lo + 8].copy()
    i = 8
    while i < n - (n % 8):
        for j in range(8):
            r[j] += a[lo + i + j]
        i += 8
    total: float = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        total += a[lo + i]
        i += 1
    return total


@jit
def _pairwise_sum(a: np.ndarray) -> float:
    """numpy's sum of a float64 vector, in numpy's order: halves (multiples of 8) down to
    blocks of 128 (numpy's recursion, run on an explicit stack: a cached kernel calling a
    recursive one crashes numba)."""
    lo = np.zeros(64, dtype=np.int64)  # frames: first element, length, phase, left sum
    ln = np.zeros(64, dtype=np.int64)
    phase = np.zeros(64, dtype=np.int64)
    left = np.zeros(64)
    ln[0] = a.shape[0]
    sp = 1
    while True:
        t = sp - 1
        if ln[t] <= 128:
            v = _block_sum(a, lo[t], ln[t])
            sp -= 1
            while sp > 0 and phase[sp - 1] == 2:  # a right half done: add it to its left
                v = left[sp - 1] + v
                sp -= 1
            if sp == 0:
                return v
            p = sp - 1  # a left half done: start the right one
            half = ln[p] // 2
            half -= half % 8
            left[p], phase[p] = v, 2
            lo[sp], ln[sp], phase[sp] = lo[p] + half, ln[p] - half, 0
            sp += 1
        else:
            half = ln[t] // 2
            half -= half % 8
            phase[t] = 1
            lo[sp], ln[sp], phase[sp] = lo[t], half, 0
            sp += 1


@jit
def weights(log_w: np.ndarray) -> np.ndarray:
    """exp(log_w - max log_w): unnormalized weights, the largest 1."""
    top = log_w[0]
    for x in log_w:
        top = _max(top, x)
    w: np.ndarray = np.exp(log_w - top)
    return w


@jit
def ess(log_w: np.ndarray, m: float) -> tuple[float, float]:
    """run._ess for weights log_w whose largest is m: (ESS, log sum exp(log_w)), with
    numpy's arithmetic in numpy's order (exp per element, _pairwise_sum)."""
    if not math.isfinite(m):
        return 0.0, m
    e = np.empty(log_w.shape[0])
    for i in range(log_w.shape[0]):
        e[i] = math.exp(log_w[i] - m)
    lse: float = m + math.log(_pairwise_sum(e))
    if not math.isfinite(lse):
        return 0.0, lse
    m2 = 2.0 * m
    for i in range(log_w.shape[0]):
        e[i] = math.exp(2.0 * log_w[i] - m2)
    return math.exp(2.0 * lse - (m2 + math.log(_pairwise_sum(e)))), lse


@jit
def residual_counts(w: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Residual resampling, first part: floor(n * w / sum w) copies of each particle, the
    fractional parts' normalized cumulative sum and how many draws are left (resample.py's
    arithmetic)."""
    m = w.shape[0]
    total = _pairwise_sum(w)
    counts = np.empty(m, dtype=np.int64)
    frac = np.empty(m)
    used = 0
    for i in range(m):
        scaled = n * (w[i] / total)
        counts[i] = int(math.floor(scaled))
        frac[i] = scaled - counts[i]
        used += counts[i]
    cum = np.empty(m)  # np.cumsum's sequential sums (a loop compiles faster than it)
    acc = 0.0
    for i in range(m):
        acc += frac[i]
        cum[i] = acc
    if n > used:
        cum /= cum[-1]
        cum[-1] = 1.0
    return counts, cum, n - used


@jit
def ancestors(counts: np.ndarray, cum: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Ancestor indices (ascending): counts[i] copies of i plus one per draw u, the
    draw's index i being the first with u < cum[i] (cum from `residual_counts`)."""
    counts = counts.copy()
    last = cum.shape[0] - 1
    for x in u:
        lo, hi = 0, cum.shape[0]  # np.searchsorted(cum, x, side="right") (compiles faster)
        while lo < hi:
            mid = (lo + hi) // 2
            c = cum[mid]
            if x < c or (c != c and x == x):  # numpy's order: NaN after every number
                hi = mid
            else:
                lo = mid + 1
        counts[min(lo, last)] += 1
    total = 0
    for c in counts:
        total += c
    out = np.empty(total, dtype=np.int64)
    pos = 0
    for i in range(counts.shape[0]):
        for _ in range(counts[i]):
            out[pos] = i
            pos += 1
    return out


@jit
def take_rows(
    image: np.ndarray,
    padded: np.ndarray,
    anc: np.ndarray,
    image_out: np.ndarray,
    padded_out: np.ndarray,
) -> None:
    """Resampling's canvas copies: row k of the outputs becomes row anc[k] (canvases and
    pyramids flattened to (N, cells): plain loops, which compile to block copies)."""
    for k in range(anc.shape[0]):
        src = anc[k]
        if not 0 <= src < image.shape[0]:
            raise IndexError("take: particle index out of range")
        for j in range(image.shape[1]):
            image_out[k, j] = image[src, j]
        for j in range(padded.shape[1]):
            padded_out[k, j] = padded[src, j]


@jit
def unpack_round(
    flat: np.ndarray,
    n_turtle: int,
    shape: np.ndarray,
    idx: np.ndarray,
    site: np.ndarray,
    turtle: np.ndarray,
    depth: np.ndarray,
    extra: np.ndarray,
    n_extra: np.ndarray,
    args: np.ndarray,
    n_args: np.ndarray,
) -> int:
    """A guided SMC round's particle state, packed by SMC into one float64 vector `flat`,
    into the rows `feature_windows` and `guide_round` read; returns the row count n.

    `flat` holds one block per site: (site, m, a, k), then m rows (particle, depth, turtle
    (n_turtle numbers), the waiting module's a parameters, the site's k prior arguments).
    Row r gets idx, site, turtle, depth (the axiom's -1 as 0), extra[r, :n_extra[r]] (the
    parameters and prior arguments fitted, cut or zero-padded, to the site's arity and
    argument count shape[s] = (arity, n_args), as features.py's columns) and args[r,
    :n_args[r]] = its k prior arguments as they are. IndexError if `flat` is malformed or
    the buffers are too small."""
    pos = 0
    r = 0
    while pos < flat.shape[0]:
        if pos + 4 > flat.shape[0]:
            raise IndexError("unpack_round: truncated block")
        s, m, a, k = int(flat[pos]), int(flat[pos + 1]), int(flat[pos + 2]), int(flat[pos + 3])
        pos += 4
        if not 0 <= s < shape.shape[0] or m < 0 or a < 0 or k < 0 or k > args.shape[1]:
            raise IndexError("unpack_round: bad block header")
        arity, na = shape[s, 0], shape[s, 1]
        width = 2 + n_turtle + a + k
        if pos + m * width > flat.shape[0] or r + m > idx.shape[0]:
            raise IndexError("unpack_round: rows out of range")
        if arity + na > extra.shape[1]:
            raise IndexError("unpack_round: extra columns too narrow")
        for _ in range(m):
            idx[r] = int(flat[pos])
            site[r] = s
            d = flat[pos + 1]
            depth[r] = d if d > 0.0 else 0.0
            for q in range(n_turtle):
                turtle[r, q] = flat[pos + 2 + q]
            at = pos + 2 + n_turtle
            for q in range(arity):
                extra[r, q] = flat[at + q] if q < a else 0.0
            for q in range(na):
                extra[r, arity + q] = flat[at + a + q] if q < k else 0.0
            n_extra[r] = arity + na
            for q in range(k):
                args[r, q] = flat[at + a + q]
            n_args[r] = k
            pos += width
            r += 1
    return r


@jit
def add_weights(
    log_w: np.ndarray, log_prior: np.ndarray, idx: np.ndarray, log_q: np.ndarray, log_p: np.ndarray
) -> None:
    """SMC's site weights of particles idx: log_w += log_p - log_q (NaN: -inf; an empty
    log_q: no change, the prior proposal), log_prior += log_p, row by row (a particle that
    repeats gets its terms in row order)."""
    guided = log_q.shape[0] > 0
    for r in range(idx.shape[0]):
        i = idx[r]
        if not 0 <= i < log_w.shape[0]:
            raise IndexError("add_weights: particle index out of range")
        if guided:
            d = log_p[r] - log_q[r]
            log_w[i] += d if d == d else -np.inf
        log_prior[i] += log_p[r]


# site kinds (sitekinds.SiteKind.code) and guide network heads of `guide_round`
NORMAL, UNIFORM, BERNOULLI, CATEGORICAL = 0, 1, 2, 3
HEAD_MIXTURE, HEAD_SIGMOID, HEAD_SOFTMAX = 0, 1, 2
LOG_2PI = float(np.log(2.0 * np.pi))  # as sitekinds.LOG_2PI
# columns of the network table `nets` (S, NET_COLS) of `guide_round`, one row per site
(NET_ON, NET_IN, NET_HIDDEN, NET_OUT, NET_HEAD, NET_K) = range(6)
(NET_W1, NET_B1, NET_W2, NET_B2, NET_BOUNDS, NET_COLS_AT) = range(6, 12)
NET_COLS = 12


@jit
def _log(v: float) -> float:
    """np.log of one float: 0 -> -inf, negative or NaN -> NaN."""
    if v > 0:
        return math.log(v)
    return -np.inf if v == 0 else np.nan


@jit
def _row_sum(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's sum of a[lo:lo + n] (a float64 vector), in numpy's order."""
    if n <= 128:
        return _block_sum(a, lo, n)
    return _pairwise_sum(a[lo : lo + n])


@jit
def _lse(a: np.ndarray, n: int) -> float:
    """sitekinds._logsumexp_rows of a[:n]: max (0 if not finite) + log sum exp(a - max)."""
    m = a[0]
    for i in range(1, n):
        m = _max(m, a[i])
    if not math.isfinite(m):
        m = 0.0
    s = np.zeros(n)
    for i in range(n):
        s[i] = math.exp(a[i] - m)
    total: float = m + _log(_row_sum(s, 0, n))
    return total


# tanh(x) ~ x P(x^2) / Q(x^2) on [-9, 9] in float32 (the rational form onnxruntime's MLAS
# and Eigen use; within 4e-7 of tanh): a loop numba vectorizes, unlike the C library's tanhf
TANH_P = np.array(
    [-2.76076847742355e-16, 2.00018790482477e-13, -8.60467152213735e-11, 5.12229709037114e-08,
     1.48572235717979e-05, 6.37261928875436e-04, 4.89352455891786e-03],
    dtype=np.float32,
)  # fmt: skip
TANH_Q = np.array(
    [1.19825839466702e-06, 1.18534705686654e-04, 2.26843463243900e-03, 4.89352518554385e-03],
    dtype=np.float32,
)


@jit
def _tanh(v: np.ndarray, n: int) -> None:
    """v[:n] = tanh(v[:n]) in float32 (the rational approximation above; NaN stays NaN)."""
    lo, hi = np.float32(-9.0), np.float32(9.0)
    p0, p1, p2, p3, p4, p5, p6 = TANH_P
    q0, q1, q2, q3 = TANH_Q
    for i in range(n):
        x = v[i]
        x = hi if x > hi else (lo if x < lo else x)
        x2 = x * x
        p = ((((((x2 * p0 + p1) * x2 + p2) * x2 + p3) * x2 + p4) * x2 + p5) * x2 + p6) * x
        q = ((x2 * q0 + q1) * x2 + q2) * x2 + q3
        v[i] = p / q


@jit
def _net(
    x: np.ndarray,
    r: int,
    t: np.ndarray,
    w: np.ndarray,
    cols: np.ndarray,
    out: np.ndarray,
    xg: np.ndarray,
    h: np.ndarray,
    o: np.ndarray,
) -> None:
    """One site network on feature row x[r] (float32, as onnxruntime): tanh(x[cols] @ w1'
    + b1), bounds * tanh(h @ w2' + b2), then its head; into out[:n_out] (xg, h, o: float32
    buffers of at least the input, hidden and output widths)."""
    n_in, hid = t[NET_IN], t[NET_HIDDEN]
    at_c, at_w = t[NET_COLS_AT], t[NET_W1]
    for i in range(n_in):  # the columns it reads, gathered first (the loop below is faster)
        xg[i] = x[r, cols[at_c + i]]
    h[:hid] = 0.0
    for i in range(n_in):
        xi = xg[i]
        wr = w[at_w + i * hid : at_w + (i + 1) * hid]
        for j in range(hid):
            h[j] += xi * wr[j]
    _finish(h, t, w, out, o)


@jit
def _net2(
    x: np.ndarray,
    r: int,
    t: np.ndarray,
    w: np.ndarray,
    cols: np.ndarray,
    out: np.ndarray,
    out2: np.ndarray,
    xg: np.ndarray,
    xg2: np.ndarray,
    h: np.ndarray,
    h2: np.ndarray,
    o: np.ndarray,
) -> None:
    """_net on rows r and r + 1 of one site, its first layer's weights read once for both
    (each row's sums in the same order as alone)."""
    n_in, hid = t[NET_IN], t[NET_HIDDEN]
    at_c, at_w = t[NET_COLS_AT], t[NET_W1]
    for i in range(n_in):
        xg[i] = x[r, cols[at_c + i]]
        xg2[i] = x[r + 1, cols[at_c + i]]
    h[:hid] = 0.0
    h2[:hid] = 0.0
    for i in range(n_in):
        xi, xi2 = xg[i], xg2[i]
        wr = w[at_w + i * hid : at_w + (i + 1) * hid]
        for j in range(hid):
            h[j] += xi * wr[j]
            h2[j] += xi2 * wr[j]
    _finish(h, t, w, out, o)
    _finish(h2, t, w, out2, o)


@jit
def _net4(
    x: np.ndarray,
    r: int,
    t: np.ndarray,
    w: np.ndarray,
    cols: np.ndarray,
    params: np.ndarray,
    xg: np.ndarray,
    hb: np.ndarray,
    o: np.ndarray,
) -> None:
    """_net on rows r to r + 3 of one site into params[r : r + 4], its first layer's
    weights read once for the four (each row's sums in the same order as alone; xg, hb:
    float32 (4, width) buffers)."""
    n_in, hid = t[NET_IN], t[NET_HIDDEN]
    at_c, at_w = t[NET_COLS_AT], t[NET_W1]
    for i in range(n_in):
        col = cols[at_c + i]
        for q in range(4):
            xg[q, i] = x[r + q, col]
    h0, h1, h2, h3 = hb[0], hb[1], hb[2], hb[3]
    h0[:hid] = 0.0
    h1[:hid] = 0.0
    h2[:hid] = 0.0
    h3[:hid] = 0.0
    for i in range(n_in):
        a, b, c, d = xg[0, i], xg[1, i], xg[2, i], xg[3, i]
        wr = w[at_w + i * hid : at_w + (i + 1) * hid]
        for j in range(hid):
            wj = wr[j]
            h0[j] += a * wj
            h1[j] += b * wj
            h2[j] += c * wj
            h3[j] += d * wj
    for q in range(4):
        _finish(hb[q], t, w, params[r + q], o)


@jit
def _finish(h: np.ndarray, t: np.ndarray, w: np.ndarray, out: np.ndarray, o: np.ndarray) -> None:
    """A site network after its first layer's sums h: + b1, tanh, bounds * tanh(h @ w2' +
    b2), then its head; into out[:n_out] (o: a float32 buffer of the output width)."""
    hid, n_out, head, k = t[NET_HIDDEN], t[NET_OUT], t[NET_HEAD], t[NET_K]
    b1 = w[t[NET_B1] : t[NET_B1] + hid]
    for j in range(hid):
        h[j] += b1[j]
    _tanh(h, hid)
    o[:n_out] = 0.0
    at_w = t[NET_W2]
    top = hid - hid % 4
    for j in range(0, top, 4):  # four hidden units a pass: each o[q] in a register, same order
        h0, h1, h2, h3 = h[j], h[j + 1], h[j + 2], h[j + 3]
        w0 = w[at_w + j * n_out : at_w + (j + 1) * n_out]
        w1 = w[at_w + (j + 1) * n_out : at_w + (j + 2) * n_out]
        w2 = w[at_w + (j + 2) * n_out : at_w + (j + 3) * n_out]
        w3 = w[at_w + (j + 3) * n_out : at_w + (j + 4) * n_out]
        for q in range(n_out):
            v = o[q]
            v += h0 * w0[q]
            v += h1 * w1[q]
            v += h2 * w2[q]
            v += h3 * w3[q]
            o[q] = v
    for j in range(top, hid):
        hj = h[j]
        wr = w[at_w + j * n_out : at_w + (j + 1) * n_out]
        for q in range(n_out):
            o[q] += hj * wr[q]
    b2 = w[t[NET_B2] : t[NET_B2] + n_out]
    for q in range(n_out):
        o[q] += b2[q]
    _tanh(o, n_out)
    bounds = w[t[NET_BOUNDS] : t[NET_BOUNDS] + n_out]
    for q in range(n_out):
        o[q] *= bounds[q]
    _head(o, n_out, head, k)
    for q in range(n_out):
        out[q] = np.float64(o[q])


@jit
def _head(o: np.ndarray, n_out: int, head: int, k: int) -> None:
    """A network's last operation on o[:n_out] (float32), in place: log-softmax over the
    first k (mixtures), sigmoid, or softmax."""
    if head == HEAD_MIXTURE:
        top = o[0]
        for q in range(1, k):
            top = max(top, o[q])
        s = np.float32(0.0)
        for q in range(k):
            o[q] = o[q] - top
            s += np.exp(o[q])
        ls = np.log(s)
        for q in range(k):
            o[q] = o[q] - ls
    elif head == HEAD_SIGMOID:
        for q in range(n_out):
            o[q] = np.float32(1.0) / (np.float32(1.0) + np.exp(-o[q]))
    else:
        top = o[0]
        for q in range(1, n_out):
            top = max(top, o[q])
        s = np.float32(0.0)
        for q in range(n_out):
            o[q] = np.exp(o[q] - top)
            s += o[q]
        for q in range(n_out):
            o[q] = o[q] / s


@jit
def _temper(kind: int, p: np.ndarray, m: int, temp: float, choice_temp: float) -> None:
    """sitekinds' tempering of one row of guide outputs p[:m], in place: mixtures' log
    weights / temp and log sds + log(temp) / 2; choices' probabilities ** (1 / choice_temp),
    renormalized (rows without a finite result: clipped, else unchanged)."""
    if kind == NORMAL or kind == UNIFORM:
        if temp != 1.0:
            k = m // 3
            for q in range(k):
                p[q] = p[q] / temp
            for q in range(2 * k, 3 * k):
                p[q] = p[q] + 0.5 * math.log(temp)
        return
    if choice_temp == 1.0:
        return
    two = kind == BERNOULLI  # the probability of 1, and of 0
    c = 2 if two else m
    pr = np.empty(c)
    for q in range(m):
        v = p[q]
        v = v if (v >= 0.0 or v != v) else 0.0
        if two and v > 1.0:
            v = 1.0
        pr[q] = v
    if two:
        pr[1] = 1.0 - pr[0]
    lp = np.empty(c)
    for q in range(c):
        lp[q] = _log(pr[q]) / choice_temp
    s = _lse(lp, c)
    finite = False
    for q in range(c):
        lp[q] = lp[q] - s
        finite = finite or math.isfinite(lp[q])
    for q in range(m):  # rows left without a finite log probability stay as they were
        p[q] = math.exp(lp[q]) if finite else pr[q]


@jit
def _normal_lp(x: float, mean: float, sd: float) -> float:
    """sitekinds._normal_logpdf of one value (sd == 0: a point mass; NaN -> -inf)."""
    if sd == 0.0:
        return 0.0 if x == mean else -np.inf
    z = (x - mean) / sd
    out = -0.5 * z * z - math.log(sd) - 0.5 * LOG_2PI if sd > 0 else np.nan
    return -np.inf if out != out else out


@jit
def _mixture_draw(
    p: np.ndarray, k: int, mu: float, sigma: float, u: float, z: float, x: float, has_x: bool
) -> tuple[float, float]:
    """A normal mixture on mu + sigma * (means), sds sigma * exp(log sds) (sitekinds'
    _normal_mixture, _mixture_sample, _mixture_logpdf): the drawn value (or x when has_x)
    and its log density."""
    lw = np.empty(k)
    for q in range(k):
        lw[q] = p[q]
    s = _lse(lw, k)
    cum = 0.0
    c = 0
    cums = np.empty(k)
    for q in range(k):
        lw[q] = lw[q] - s
        cum += math.exp(lw[q])
        cums[q] = cum
    if not has_x:
        at = u * cums[k - 1]
        for q in range(k):
            if cums[q] <= at:
                c += 1
        c = min(c, k - 1)
        x = (mu + sigma * p[k + c]) + (sigma * math.exp(p[2 * k + c])) * z
    comp = np.empty(k)
    for q in range(k):
        comp[q] = lw[q] + _normal_lp(x, mu + sigma * p[k + q], sigma * math.exp(p[2 * k + q]))
    return x, _lse(comp, k)


@jit
def _choice_draw(p: np.ndarray, m: int, u: float) -> tuple[float, float]:
    """A categorical proposal over p[:m] (sitekinds.Categorical.proposal_draw): the index
    drawn and its log probability."""
    ok = True
    for q in range(m):
        if not p[q] >= 0.0:
            ok = False
    total = _row_sum(p, 0, m)
    pr = np.empty(m)
    if ok and total > 0:
        for q in range(m):
            pr[q] = p[q]
    else:  # _probs: clipped at 0, normalized, uniform where the sum is not positive
        for q in range(m):
            pr[q] = p[q] if (p[q] >= 0.0 or p[q] != p[q]) else 0.0
        t2 = _row_sum(pr, 0, m)
        for q in range(m):
            pr[q] = pr[q] / t2 if t2 > 0 else 1.0 / m
        total = 1.0
    cum = np.empty(m)
    acc = 0.0
    for q in range(m):
        acc += pr[q]
        cum[q] = acc
    at = u * cum[m - 1]
    c = 0
    for q in range(m):
        if cum[q] <= at:
            c += 1
    c = min(c, m - 1)
    q_c = pr[c] / total if ok else pr[c]
    return float(c), _log(q_c)


@jit
def _prior_lp(kind: int, a: np.ndarray, na: int, x: float) -> float:
    """sitekinds' prior_logpdf of value x under prior arguments a[:na]."""
    if kind == NORMAL:
        return _normal_lp(x, a[0], abs(a[1]))
    if kind == UNIFORM:
        lo, hi = _min(a[0], a[1]), _max(a[0], a[1])
        width = hi - lo
        if not (lo <= x <= hi) or not (width > 0 or x == lo):
            return -np.inf
        return -math.log(width) if width > 0 else 0.0
    if kind == BERNOULLI:
        pb = _min(_max(a[0], 0.0), 1.0)
        if x == 1.0:
            return _log(pb)
        if x == 0.0:
            return _log(1.0 - pb)
        return -np.inf
    if not (x >= 0 and x < na and x == math.floor(x)):
        return -np.inf
    return _log(a[int(x)] / _row_sum(a, 0, na))


@jit
def _args_ok(kind: int, a: np.ndarray, na: int) -> bool:
    """Prior arguments distributions accepts: finite (categorical: finite, >= 0, with a
    positive sum)."""
    for q in range(na):
        if not math.isfinite(a[q]):
            return False
        if kind == CATEGORICAL and a[q] < 0:
            return False
    return kind != CATEGORICAL or _row_sum(a, 0, na) > 0


@jit
def guide_round(
    x: np.ndarray,
    site: np.ndarray,
    nets: np.ndarray,
    w: np.ndarray,
    cols: np.ndarray,
    kinds: np.ndarray,
    temps: np.ndarray,
    params: np.ndarray,
    n_par: np.ndarray,
    args: np.ndarray,
    n_args: np.ndarray,
    u: np.ndarray,
    z: np.ndarray,
    out: np.ndarray,
) -> int:
    """A guided SMC round over n rows: row r at site s = site[r] gets its proposal
    parameters params[r, :n_par[r]] (float64), from the site's network on feature row x[r]
    when nets[s, NET_ON] (else as given), tempered by temps = (temperature, choice
    temperature); then, when out has rows, a value drawn from that proposal with the
    uniform u[r] and the standard normal z[r] (mixtures), and out[r] = (value, log q,
    log prior) (prior arguments args[r, :n_args[r]]). kinds[s]: the site's kind code.
    Returns the first row whose prior arguments are not valid, else -1 (its log prior is
    not meaningful)."""
    n = site.shape[0]
    draw = out.shape[0] > 0
    bad = -1
    width = 1
    for s in range(nets.shape[0]):
        width = max(width, nets[s, NET_IN], nets[s, NET_HIDDEN], nets[s, NET_OUT])
    xg = np.empty(width, dtype=np.float32)
    xg2 = np.empty(width, dtype=np.float32)
    h = np.empty(width, dtype=np.float32)
    h2 = np.empty(width, dtype=np.float32)
    o = np.empty(width, dtype=np.float32)
    xg4 = np.empty((4, width), dtype=np.float32)
    h4 = np.empty((4, width), dtype=np.float32)
    done = -1  # the last row whose network ran with a row before it
    for r in range(n):
        s = site[r]
        t = nets[s]
        p = params[r]
        if t[NET_ON] and r > done:
            if r + 3 < n and site[r + 1] == s and site[r + 2] == s and site[r + 3] == s:
                _net4(x, r, t, w, cols, params, xg4, h4, o)
                done = r + 3
            elif r + 1 < n and site[r + 1] == s:
                _net2(x, r, t, w, cols, p, params[r + 1], xg, xg2, h, h2, o)
                done = r + 1
            else:
                _net(x, r, t, w, cols, p, xg, h, o)
        kind, m = kinds[s], n_par[r]
        _temper(kind, p, m, temps[0], temps[1])
        if not draw:
            continue
        a = args[r]
        if n_args[r] < (2 if kind <= UNIFORM else 1) or a.shape[0] < n_args[r]:
            bad = r if bad < 0 else bad
            out[r, 0], out[r, 1], out[r, 2] = np.nan, np.nan, np.nan
            continue
        if bad < 0 and not _args_ok(kind, a, n_args[r]):
            bad = r
        if kind == NORMAL:
            v, lq = _mixture_draw(p, m // 3, a[0], abs(a[1]), u[r], z[r], 0.0, False)
        elif kind == UNIFORM:
            lo, hi = _min(a[0], a[1]), _max(a[0], a[1])
            zz, _ = _mixture_draw(p, m // 3, 0.0, 1.0, u[r], z[r], 0.0, False)
            v = lo + (hi - lo) / (1.0 + math.exp(-zz))
            lq = _uniform_lq(p, m // 3, lo, hi, v)
        elif kind == BERNOULLI:
            pb = p[0] if p[0] != p[0] else _min(_max(p[0], 0.0), 1.0)
            v = 1.0 if u[r] < pb else 0.0
            q1 = pb if v == 1.0 else 1.0 - pb
            lq = _log(q1)
        else:
            v, lq = _choice_draw(p, m, u[r])
        out[r, 0] = v
        out[r, 1] = lq
        out[r, 2] = _prior_lp(kind, a, n_args[r], v)
    return bad


@jit
def serve_round(
    flat: np.ndarray,
    n_turtle: int,
    shape: np.ndarray,
    idx: np.ndarray,
    site: np.ndarray,
    turtle: np.ndarray,
    depth: np.ndarray,
    extra: np.ndarray,
    n_extra: np.ndarray,
    args: np.ndarray,
    n_args: np.ndarray,
    x: np.ndarray,
    view: np.ndarray,
    size: np.ndarray,
    offs: np.ndarray,
    target: np.ndarray,
    canvas: np.ndarray,
    ctx: np.ndarray,
    ctx_geom: np.ndarray,
    cells: np.ndarray,
    cell_t: np.ndarray,
    table: np.ndarray,
    w: np.ndarray,
    cols: np.ndarray,
    kinds: np.ndarray,
    temps: np.ndarray,
    n_out: np.ndarray,
    params: np.ndarray,
    u: np.ndarray,
    z: np.ndarray,
    out: np.ndarray,
    log_w: np.ndarray,
    log_prior: np.ndarray,
    memo: np.ndarray,
    memo_key: np.ndarray,
) -> tuple[int, int]:
    """A guided SMC round whose every site has a network here, in one call: the packed
    state into the rows (unpack_round's arguments, flat to n_args), their features into x
    (feature_windows', view to cell_t), proposal parameters, draws, log q and log prior
    into out (guide_round's, table to n_out: the outputs per site) and the site weights
    into log_w and log_prior (add_weights; not when a row's prior arguments are bad);
    memo, memo_key: feature_windows' (NO_MEMO, NO_MEMO_KEY: none). The same kernels in the
    same order as the round's separate calls, so every number is theirs. Flat arguments:
    numba's dispatch types arrays fast, tuples slowly. Returns (row count, first bad row
    or -1)."""
    n = unpack_round(flat, n_turtle, shape, idx, site, turtle, depth, extra, n_extra, args, n_args)
    xr = x[:n]
    feature_windows(
        xr,
        turtle[:n],
        depth[:n],
        idx[:n],
        view,
        size,
        offs,
        target,
        canvas,
        ctx,
        ctx_geom,
        cells,
        cell_t,
        extra[:n],
        n_extra[:n],
        memo,
        memo_key,
    )
    n_par = np.empty(n, dtype=np.int64)
    for r in range(n):
        n_par[r] = n_out[site[r]]
    o = out[:n]
    bad = guide_round(
        xr, site[:n], table, w, cols, kinds, temps, params[:n], n_par, args[:n], n_args[:n], u, z, o
    )
    if bad < 0:
        add_weights(log_w, log_prior, idx[:n], o[:, 1], o[:, 2])
    return n, bad


@jit
def _uniform_lq(p: np.ndarray, k: int, lo: float, hi: float, v: float) -> float:
    """Log density of v under the logit-normal mixture proposal on (lo, hi)
    (sitekinds.Uniform.proposal_logpdf)."""
    width = hi - lo
    uu = (v - lo) / width if width != 0 else np.nan
    if not (width > 0 and 0 < uu < 1):
        return -np.inf
    zz = math.log(uu) - math.log1p(-uu)
    _, lz = _mixture_draw(p, k, 0.0, 1.0, 0.0, 0.0, zz, True)
    out = lz - (math.log(width) + math.log(uu) + math.log1p(-uu))
    return -np.inf if out != out else out
