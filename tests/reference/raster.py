"""The numpy rasterizer the compiled draw kernel replaced (ngpm_runtime/kernels.py), kept
as the tests' reference: `Canvas` draws and resamples as the runtime's did before numba,
one numpy pass per primitive kind (git history: runtime/ngpm_runtime/image/raster.py)."""

from __future__ import annotations

import numpy as np
from ngpm_runtime.geometry.turtle import Prim, prim_bboxes
from ngpm_runtime.image.raster import (
    N_LEVELS,
    PAD,
    DrawBatch,
    Viewport,
    as_viewport,
    level_shapes,
    padded_layout,
    padded_pyramid,
)

_EPS = 1e-9
_CHUNK = 8192  # window pixels per vectorized shape test: float64 temporaries <= 64 KiB


def _cover(
    kind: str, P: np.ndarray | None, prims: list[Prim], px: np.ndarray, py: np.ndarray
) -> np.ndarray:
    """Coverage (g, ky, kx) of pixel centers px (g, kx), py (g, ky) by g primitives."""
    if kind == "poly":
        out = np.zeros((len(prims), py.shape[1], px.shape[1]), dtype=bool)
        for k, p in enumerate(prims):
            out[k] = _poly_inside(
                np.asarray(p[1], dtype=np.float64).reshape(-1, 2), px[k][None, :], py[k][:, None]
            )
        return out
    assert P is not None  # every kind but "poly" has a parameter array
    # Work in (ky, kx, g) layout: the primitive axis is last, so numpy's inner loops run
    # over all g primitives instead of over a few window pixels.
    X = np.ascontiguousarray(px.T)[None, :, :]  # (1, kx, g)
    Y = np.ascontiguousarray(py.T)[:, None, :]  # (ky, 1, g)
    if kind == "seg":
        ax, ay, bx, by, w = P.T
        ex, ey = bx - ax, by - ay
        l2 = ex * ex + ey * ey
        inv = np.divide(1.0, l2, out=np.zeros_like(l2), where=l2 > 0)
        dx, dy = X - ax, Y - ay
        t = dx * (ex * inv) + dy * (ey * inv)  # projection parameter along the segment
        np.maximum(t, 0.0, out=t)
        np.minimum(t, 1.0, out=t)
        qx = dx - t * ex
        qy = dy - t * ey
        qx *= qx
        qy *= qy
        qx += qy
        res = qx < (w * w) / 4.0
    elif kind == "disk":
        x, y, r = P.T
        dx, dy = X - x, Y - y
        res = dx * dx + dy * dy < r * r
    elif kind == "leaf":
        x, y, h, length, width = P.T
        c, s = np.cos(np.radians(h)), np.sin(np.radians(h))
        a, b = np.abs(length) / 2.0, np.abs(width) / 2.0
        dx, dy = X - (x + length / 2.0 * c), Y - (y + length / 2.0 * s)
        u = dx * (c * b) + dy * (s * b)  # scaled local coordinates along / across
        v = dy * (c * a) - dx * (s * a)
        u *= u
        v *= v
        u += v
        res = u < (a * b) ** 2
    else:
        raise ValueError(f"unknown primitive kind {kind!r}")
    return np.ascontiguousarray(res.transpose(2, 0, 1))


def _poly_inside(verts: np.ndarray, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Even-odd rule: pixel centers (X, Y broadcast) inside the closed polygon `verts`."""
    inside = np.zeros(np.broadcast_shapes(X.shape, Y.shape), dtype=bool)
    m = len(verts)
    if m < 3:
        return inside
    for i in range(m):
        xi, yi = verts[i]
        xj, yj = verts[i - 1]
        if yi == yj:
            continue  # horizontal edges never cross a horizontal ray
        crosses = (yi > Y) != (yj > Y)
        xint = xi + (Y - yi) * (xj - xi) / (yj - yi)
        inside ^= crosses & (X < xint)
    return inside


# ---------------------------------------------------------------- windows


_LO = [0, 3]  # bbox columns of the (x, y) pixel-space lower corner: xmin, ymax
_HI = [2, 1]  # and of the upper corner: xmax, ymin


class _Grid:
    """Pixel geometry of a viewport on an H x W image."""

    def __init__(self, viewport: Viewport, height: int, width: int) -> None:
        xmin, xmax, ymin, ymax = (float(v) for v in viewport)
        if not (xmax > xmin and ymax > ymin):
            raise ValueError(f"empty viewport {viewport!r}")
        self.xmin, self.ymax = xmin, ymax
        self.h, self.w = int(height), int(width)
        self.sx = (xmax - xmin) / self.w
        self.sy = (ymax - ymin) / self.h
        # windows(): per (x, y) column, origin, signed scale, upper clamp and last pixel
        self._org = np.array([xmin, ymax])
        self._scale = np.array([self.sx, -self.sy])
        self._lim = np.array([self.w + 1.0, self.h + 1.0])
        self._last = np.array([self.w - 1.0, self.h - 1.0])

    def windows(self, bbox: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, int, np.ndarray]:
        """Common window (ky, kx) and origins y0, x0 holding every box's pixel centers."""
        h, w = self.h, self.w
        # columns (x, y): pixel-center coordinates of the box corners, x right, y down
        # ((b - ymax) / -sy equals (ymax - b) / sy exactly)
        lo = (bbox[:, _LO] - self._org) / self._scale - 0.5
        hi = (bbox[:, _HI] - self._org) / self._scale - 0.5
        with np.errstate(invalid="ignore"):
            lo -= _EPS
            hi += _EPS
            np.maximum(lo, -1.0, out=lo)
            np.maximum(hi, -1.0, out=hi)
            np.minimum(lo, self._lim, out=lo)
            np.minimum(hi, self._lim, out=hi)
            np.ceil(lo, out=lo)
            np.floor(hi, out=hi)
        finite = np.isfinite(bbox).all(axis=1)[:, None]
        lo = np.where(finite, np.maximum(lo, 0.0), 0.0).astype(np.intp)
        hi = np.where(finite, np.minimum(hi, self._last), -1.0).astype(np.intp)
        empty = np.any(hi < lo, axis=1)
        size = hi - lo + 1
        if empty.any():
            size = size[~empty]
        kx, ky = size.max(axis=0).tolist() if len(size) else (1, 1)
        kx, ky = min(max(1, kx), w), min(max(1, ky), h)
        org = np.minimum(lo, (w - kx, h - ky))
        org[empty] = 0
        return org[:, 1], org[:, 0], ky, kx, empty

    def cover(self, prims: list[Prim]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Rasterize prims: y0, x0 (n,), coverage (n, ky, kx) bool, world bbox (n, 4)."""
        n = len(prims)
        kinds = [p[0] for p in prims]
        groups: dict[str, list[int]] = {}
        if n and kinds.count(kinds[0]) == n:
            groups[kinds[0]] = list(range(n))  # the common case: one kind
        else:
            for k, kind in enumerate(kinds):
                groups.setdefault(kind, []).append(k)
        bbox = np.empty((n, 4))
        params: dict[str, np.ndarray | None] = {}
        for kind, pos in groups.items():
            sel = prims if len(pos) == n else [prims[k] for k in pos]
            b, params[kind] = prim_bboxes(kind, sel)
            if len(pos) == n:
                bbox[:] = b
            else:
                bbox[pos] = b
        y0, x0, ky, kx, empty = self.windows(bbox)
        cov = np.zeros((n, ky, kx), dtype=bool)
        ax, ay = np.arange(kx) + 0.5, np.arange(ky) + 0.5
        # chunks keep the float64 temporaries small (cache-sized, no mmap per temporary)
        step = max(16, _CHUNK // (ky * kx))
        for kind, pos in groups.items():
            whole = len(pos) == n
            pa = slice(None) if whole else np.asarray(pos)
            px = self.xmin + (x0[pa, None] + ax) * self.sx
            py = self.ymax - (y0[pa, None] + ay) * self.sy
            P = params[kind]
            sub = cov if whole else np.empty((len(pos), ky, kx), dtype=bool)
            with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
                for s in range(0, len(pos), step):  # non-finite geometry: window is empty
                    e = s + step
                    sub[s:e] = _cover(
                        kind,
                        None if P is None else P[s:e],
                        [prims[k] for k in pos[s:e]],
                        px[s:e],
                        py[s:e],
                    )
            if not whole:
                cov[pa] = sub
        if empty.any():
            cov[empty] = False
        return y0, x0, cov, bbox


def prim_mask(
    prim: Prim, viewport: Viewport, height: int, width: int
) -> tuple[int, int, np.ndarray]:
    """One primitive's full coverage: (y0, x0, mask (ky, kx) bool) on an H x W image."""
    y0, x0, cov, _ = _Grid(viewport, height, width).cover([prim])
    return int(y0[0]), int(x0[0]), cov[0]


def rasterize(prims: list[Prim], viewport: Viewport, height: int, width: int) -> np.ndarray:
    """The (H, W) uint8 image of all prims, one primitive at a time (scratch rendering)."""
    img = np.zeros((height, width), dtype=np.uint8)
    grid = _Grid(viewport, height, width)
    for p in prims:
        y0, x0, cov, _ = grid.cover([p])
        ky, kx = cov.shape[1:]
        img[y0[0] : y0[0] + ky, x0[0] : x0[0] + kx] |= cov[0]
    return img


# ---------------------------------------------------------------- canvas


class Canvas:
    """N binary canvases `(N, H, W)` uint8 with an incrementally kept 4-level pyramid.

    `padded` (N, total) float32 holds every canvas's pyramid in `padded_layout` (level 0 the
    image as 0/1, levels 1-3 means over 2x2, 4x4 and 8x8 pixel blocks, floor sizes; -1 in
    the padding). `levels` gives the unpadded levels as views (`levels[0]` is `image`).
    With `pyramid=False` (no guide features to serve) only `image` is kept: `padded` is
    (N, 0) and `levels` is `[image]`.
    """

    def __init__(
        self, n: int, height: int, width: int, viewport: Viewport, pyramid: bool = True
    ) -> None:
        self.n, self.height, self.width = int(n), int(height), int(width)
        self.viewport = as_viewport(viewport)
        self._grid = _Grid(self.viewport, self.height, self.width)
        self.image = np.zeros((self.n, self.height, self.width), dtype=np.uint8)
        self._hp, self._wp, self._starts = padded_layout(self.height, self.width)
        self.pyramid = pyramid
        # draw(): levels 1.., their (heights, widths), each level's first cell in a padded
        # row (start + padding) and its weight per pixel (1 / 4^level, float32)
        lv = np.arange(1, N_LEVELS, dtype=np.intp)
        self._up = (
            lv,
            np.stack([self.height >> lv, self.width >> lv]),
            self._starts[1:] + PAD * self._wp[1:] + PAD,
            (1.0 / 4.0**lv).astype(np.float32),
        )
        blank = padded_pyramid(
            [np.zeros(s, dtype=np.float32) for s in level_shapes(self.height, self.width)]
        )
        self.padded = np.repeat(blank[None, :] if pyramid else blank[None, :0], self.n, axis=0)
        self._spare: list[np.ndarray] | None = None  # take()'s second buffers
        self._row_off = np.arange(self.height)[:, None] * self.width  # (H, 1) flat offsets

    @property
    def levels(self) -> list[np.ndarray]:
        """The pyramid levels (N, h_l, w_l): `image`, then float32 views into `padded`."""
        out = [self.image]
        for lv, (h, w) in enumerate(level_shapes(self.height, self.width)):
            if lv and self.pyramid:
                hp, wp, st = int(self._hp[lv]), int(self._wp[lv]), int(self._starts[lv])
                block = self.padded[:, st : st + hp * wp].reshape(self.n, hp, wp)
                out.append(block[:, PAD : PAD + h, PAD : PAD + w])
        return out

    def draw(self, idx: np.ndarray, prims: list[Prim]) -> DrawBatch:
        """Rasterize `prims[k]` into canvas `idx[k]` (indices distinct); returns the changes."""
        idx = np.asarray(idx, dtype=np.intp).reshape(-1)
        if len(prims) != len(idx):
            raise ValueError("draw: one primitive per listed particle")
        y0, x0, cov, bbox = self._grid.cover(prims)
        h, w = self.height, self.width
        ky, kx = cov.shape[1:]
        itype = np.int32 if self.n * h * w < 2**31 else np.intp  # small index temporaries
        base = (idx * (h * w) + y0 * w + x0).astype(itype)
        off = (self._row_off[:ky] + np.arange(kx)).astype(itype)
        flat = base[:, None, None] + off  # (n, ky, kx) global pixel indices
        img = self.image.reshape(-1)
        new = cov & (img[flat] == 0)
        k, i, j = np.nonzero(new)
        r = y0[k] + i
        c = x0[k] + j
        p = idx[k]
        img[(p * h + r) * w + c] = 1
        if k.size and self.pyramid:
            pad = self.padded.reshape(-1)
            row0 = p * self.padded.shape[1]
            wp, starts = self._wp, self._starts
            pad[row0 + starts[0] + (r + PAD) * wp[0] + (c + PAD)] = 1.0
            # levels 1..3 in one add.at, (pixel, level) in row-major order: every cell
            # belongs to one level and gets its pixels' additions in the same order as a
            # loop over levels would give them (the same float32 sums)
            lv, size, first, wts = self._up
            rl, cl = r[:, None] >> lv, c[:, None] >> lv
            ok = (rl < size[0]) & (cl < size[1])
            at = row0[:, None] + first + rl * wp[1:] + cl
            np.add.at(pad, at[ok], np.broadcast_to(wts, ok.shape)[ok])
        return DrawBatch(idx=idx, y0=y0, x0=x0, new=new, bbox=bbox, hit_k=k, hit_pix=r * w + c)

    def take(self, idx: np.ndarray) -> None:
        """Resampling: particle k becomes old particle idx[k] (every per-particle array).

        The arrays are double-buffered (fresh allocations of this size cost page faults):
        a reference to `image` or `padded` kept across two `take` calls gets overwritten.
        """
        idx = np.asarray(idx, dtype=np.intp).reshape(-1)
        if len(idx) != self.n:
            self.image = self.image[idx]
            self.padded = self.padded[idx]
            self.n = len(idx)
            self._spare = None
            return
        if self._spare is None:
            self._spare = [np.empty_like(self.image), np.empty_like(self.padded)]
        img, pad = self._spare
        np.take(self.image, idx, axis=0, out=img)
        np.take(self.padded, idx, axis=0, out=pad)
        self._spare = [self.image, self.padded]
        self.image, self.padded = img, pad
