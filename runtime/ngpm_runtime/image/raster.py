"""Rasterization of turtle primitives into per-particle binary canvases (architecture.md 7-8).

A viewport `(xmin, xmax, ymin, ymax)` maps the world onto an H x W image: x right, y up,
pixel row 0 at ymax. A pixel is covered when its center lies strictly inside the shape.
`Canvas.draw` rasterizes one primitive per listed particle, all in one compiled call
(ngpm_runtime.kernels.draw), inside a common pixel window, and keeps a 4-level mean pyramid
of every canvas up to date (pixels are only ever added, so each level just accumulates
counts).
The pyramid lives in one float32 row per particle, `Canvas.padded`: the levels one after
another, each with PAD cells of -1 around it (`padded_layout`), so that the guide features'
3x3 windows at every level are one gather (features.py) and resampling copies rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import chain
from typing import Any

import numpy as np

from ngpm_runtime.geometry.turtle import Prim, prim_bboxes, prim_params

Viewport = tuple[float, float, float, float]  # (xmin, xmax, ymin, ymax)
N_LEVELS = 4
PAD = 3  # cells of -1 around each pyramid level in `Canvas.padded`


@dataclass
class DrawBatch:
    """What one `Canvas.draw` call changed.

    `new[k]` covers canvas pixels `[y0[k]:y0[k]+ky, x0[k]:x0[k]+kx]` of particle `idx[k]`
    (windows always lie inside the image); `bbox[k]` is the primitive's world box
    `(xmin, ymin, xmax, ymax)`.
    """

    idx: np.ndarray  # (n,) intp particle indices
    y0: np.ndarray  # (n,) intp
    x0: np.ndarray  # (n,) intp
    new: np.ndarray  # (n, ky, kx) bool: newly covered pixels
    bbox: np.ndarray  # (n, 4) float64
    # the newly covered pixels as a list (optional; filled by Canvas.draw):
    hit_k: np.ndarray | None = None  # (m,) batch row k of each new pixel
    hit_pix: np.ndarray | None = None  # (m,) its pixel index row * W + col in the image
    prims: list[Prim] | None = None  # the drawn primitives (smc sets them for the likelihood)

    def hits(self, width: int) -> tuple[np.ndarray, np.ndarray]:
        """(batch rows, pixel indices row * width + col) of every newly covered pixel."""
        if self.hit_k is not None and self.hit_pix is not None:
            return self.hit_k, self.hit_pix
        k, i, j = np.nonzero(self.new)
        return k, (self.y0[k] + i) * width + self.x0[k] + j


def as_viewport(viewport: Sequence[float]) -> Viewport:
    """`viewport` as four floats (xmin, xmax, ymin, ymax)."""
    xmin, xmax, ymin, ymax = (float(v) for v in viewport)
    return xmin, xmax, ymin, ymax


def level_shapes(height: int, width: int) -> list[tuple[int, int]]:
    """Pyramid level sizes: (H, W), (H//2, W//2), (H//4, W//4), (H//8, W//8)."""
    return [(height >> lv, width >> lv) for lv in range(N_LEVELS)]


def padded_layout(height: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pyramid level of an H x W image: padded height and width (each level's size plus
    2 * PAD) and the level's start in the padded row (intp arrays)."""
    hs = np.array([height >> lv for lv in range(N_LEVELS)], dtype=np.intp)
    ws = np.array([width >> lv for lv in range(N_LEVELS)], dtype=np.intp)
    hp, wp = hs + 2 * PAD, ws + 2 * PAD
    starts = np.concatenate([[0], np.cumsum(hp * wp)[:-1]]).astype(np.intp)
    return hp, wp, starts


def padded_pyramid(levels: list[np.ndarray]) -> np.ndarray:
    """Pyramid levels (each (..., h_l, w_l)) in the padded layout: (..., total) float32,
    -1 in the padding."""
    rows = []
    for lev in levels:
        lead = lev.shape[:-2]
        p = np.full(
            lead + (lev.shape[-2] + 2 * PAD, lev.shape[-1] + 2 * PAD), -1.0, dtype=np.float32
        )
        p[..., PAD : PAD + lev.shape[-2], PAD : PAD + lev.shape[-1]] = lev
        rows.append(p.reshape(lead + (-1,)))
    return np.concatenate(rows, axis=-1)


def pyramid(image: np.ndarray) -> list[np.ndarray]:
    """4-level 2x2-mean pyramid of `image` (..., H, W), computed from scratch (float32)."""
    img = np.asarray(image, dtype=np.float64)
    out = [img.astype(np.float32)]
    cur = img
    for _ in range(1, N_LEVELS):
        h, w = cur.shape[-2] // 2, cur.shape[-1] // 2
        cur = cur[..., : 2 * h, : 2 * w]
        cur = 0.25 * (
            cur[..., 0::2, 0::2]
            + cur[..., 1::2, 0::2]
            + cur[..., 0::2, 1::2]
            + cur[..., 1::2, 1::2]
        )
        out.append(cur.astype(np.float32))
    return out


# ---------------------------------------------------------------- packing for the kernel


_CODES = {"seg": 0, "disk": 1, "leaf": 2, "poly": 3}  # kernels.SEG, DISK, LEAF, POLY
_NO_VERTS = np.zeros((0, 2))
_PAD = (0.0,) * 5  # pads a primitive's parameters to the kernel's 5 columns
_RASTER_CHUNK = 64  # primitives per kernel call in `rasterize`


def _kernels() -> Any:
    """The compiled kernels (ngpm_runtime.kernels), imported on first use: numba loads
    only when something is drawn."""
    from ngpm_runtime import kernels

    return kernels


def _pack(prims: list[Prim]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Primitives as the draw kernel takes them: kind codes (n,), parameters (n, k) (all
    but the kind), polygon vertices (m, 2) and each primitive's first vertex (n + 1,)."""
    n = len(prims)
    kind = prims[0][0] if n else "seg"
    if kind != "poly" and all(p[0] == kind for p in prims):  # the common case: one kind
        if kind not in _CODES:
            raise ValueError(f"unknown primitive kind {kind!r}")
        return (
            np.full(n, _CODES[kind], dtype=np.int8),
            prim_params(prims),
            _NO_VERTS,
            np.zeros(n + 1, dtype=np.intp),
        )
    try:
        codes = np.fromiter([_CODES[p[0]] for p in prims], np.int8, n)
    except KeyError as err:
        raise ValueError(f"unknown primitive kind {err.args[0]!r}") from None
    if not (codes == _CODES["poly"]).any():  # mixed kinds without polygons: one flat list
        # a generator, so that the padded rows are not all alive at once (the garbage
        # collector runs by the count of container objects alive)
        flat = list(
            chain.from_iterable(p if len(p) == 6 else p + _PAD[len(p) - 1 :] for p in prims)
        )
        if len(flat) != 6 * n:
            raise ValueError("a primitive has more than 5 parameters")
        del flat[::6]  # the kind names
        par = np.fromiter(flat, np.float64, 5 * n).reshape(n, 5)
        return codes, par, _NO_VERTS, np.zeros(n + 1, dtype=np.intp)
    par = np.zeros((n, 5))
    verts: list[np.ndarray] = []
    vstart = np.zeros(n + 1, dtype=np.intp)
    for k, p in enumerate(prims):
        if p[0] == "poly":
            v = np.asarray(p[1], dtype=np.float64).reshape(-1, 2)
            verts.append(v)
            vstart[k + 1] = vstart[k] + len(v)
        else:
            par[k, : len(p) - 1] = p[1:]
            vstart[k + 1] = vstart[k]
    return codes, par, np.concatenate(verts) if verts else _NO_VERTS, vstart


def _view(viewport: Viewport, height: int, width: int) -> np.ndarray:
    """(xmin, ymax, pixel width, pixel height) of a viewport on an H x W image."""
    xmin, xmax, ymin, ymax = (float(v) for v in viewport)
    if not (xmax > xmin and ymax > ymin):
        raise ValueError(f"empty viewport {viewport!r}")
    return np.array([xmin, ymax, (xmax - xmin) / int(width), (ymax - ymin) / int(height)])


def prim_mask(
    prim: Prim, viewport: Viewport, height: int, width: int
) -> tuple[int, int, np.ndarray]:
    """One primitive's full coverage: (y0, x0, mask (ky, kx) bool) on an H x W image."""
    canvas = Canvas(1, height, width, viewport, pyramid=False)
    batch = canvas.draw(np.zeros(1, dtype=np.intp), [prim])
    return int(batch.y0[0]), int(batch.x0[0]), batch.new[0]


def rasterize(prims: list[Prim], viewport: Viewport, height: int, width: int) -> np.ndarray:
    """The (H, W) uint8 image of all prims (scratch rendering)."""
    canvas = Canvas(1, height, width, viewport, pyramid=False)
    for s in range(0, len(prims), _RASTER_CHUNK):  # the kernel draws repeated rows in turn
        chunk = prims[s : s + _RASTER_CHUNK]
        canvas.draw(np.zeros(len(chunk), dtype=np.intp), chunk)
    image: np.ndarray = canvas.image[0]
    return image


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
        self._k = _kernels()
        self._view = _view(self.viewport, self.height, self.width)
        self.image = np.zeros((self.n, self.height, self.width), dtype=np.uint8)
        self._hp, self._wp, self._starts = padded_layout(self.height, self.width)
        self.pyramid = pyramid
        if pyramid:
            blank = padded_pyramid(
                [np.zeros(s, dtype=np.float32) for s in level_shapes(self.height, self.width)]
            )
            self.padded = np.repeat(blank[None, :], self.n, axis=0)
        else:  # no blank pyramid built (render_frames makes one such canvas per primitive)
            self.padded = np.zeros((self.n, 0), dtype=np.float32)
        self._spare: list[np.ndarray] | None = None  # take()'s second buffers

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
        """Rasterize `prims[k]` into canvas `idx[k]` (one compiled call for the batch;
        SMC's indices are distinct, a repeated one draws its primitives in turn); returns
        the changes."""
        idx = np.asarray(idx, dtype=np.intp).reshape(-1)
        if len(prims) != len(idx):
            raise ValueError("draw: one primitive per listed particle")
        return self.draw_packed(idx, *_pack(prims))

    def draw_packed(
        self,
        idx: np.ndarray,
        codes: np.ndarray,
        par: np.ndarray,
        verts: np.ndarray = _NO_VERTS,
        vstart: np.ndarray | None = None,
    ) -> DrawBatch:
        """`draw` of primitives given as the draw kernel takes them (`_pack`'s arrays:
        kind codes, parameters (n, <= 5), polygon vertices and their starts)."""
        if vstart is None:
            vstart = np.zeros(len(idx) + 1, dtype=np.intp)
        bbox, y0, x0, new, hit_k, hit_pix = self._k.draw(
            self.image, self.padded, idx, codes, par, verts, vstart, *self.layout()
        )
        return DrawBatch(idx=idx, y0=y0, x0=x0, new=new, bbox=bbox, hit_k=hit_k, hit_pix=hit_pix)

    def layout(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The draw kernel's view of the canvas (kernels.draw's view, wp, starts)."""
        return self._view, self._wp, self._starts

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
        image, padded, image_out, padded_out = self.take_args()
        self._k.take_rows(image, padded, idx, image_out, padded_out)
        self.swap()

    def take_args(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """kernels.take_rows' rows and outputs (canvases flattened to (N, cells), pyramids,
        then the spare arrays they go into); `swap` makes the spares the canvas after."""
        if self._spare is None:
            self._spare = [np.empty_like(self.image), np.empty_like(self.padded)]
        img, pad = self._spare
        n = self.n
        return self.image.reshape(n, -1), self.padded, img.reshape(n, -1), pad

    def swap(self) -> None:
        """The spare arrays (filled by a take) become the canvas, the canvas the spares."""
        assert self._spare is not None
        img, pad = self._spare
        self._spare = [self.image, self.padded]
        self.image, self.padded = img, pad


def bbox_of(prims: list[Prim]) -> np.ndarray:
    """World box (4,) = (xmin, ymin, xmax, ymax) of all prims; +-inf when there are none."""
    out = np.array([np.inf, np.inf, -np.inf, -np.inf])
    groups: dict[str, list[Prim]] = {}
    for p in prims:
        groups.setdefault(p[0], []).append(p)
    for kind, group in groups.items():
        b = prim_bboxes(kind, group)[0]
        out[:2] = np.minimum(out[:2], b[:, :2].min(axis=0))
        out[2:] = np.maximum(out[2:], b[:, 2:].max(axis=0))
    return out


def viewport_of(prims: list[Prim], margin: float = 0.05) -> Viewport:
    """A square viewport fitting every primitive, with a relative margin."""
    if not prims:
        return (-1.0, 1.0, -1.0, 1.0)
    boxes = [prim_bboxes(p[0], [p])[0][0] for p in prims]
    b = np.array(boxes)
    b = b[np.isfinite(b).all(axis=1)]
    if len(b) == 0:
        return (-1.0, 1.0, -1.0, 1.0)
    xmin, ymin = b[:, 0].min(), b[:, 1].min()
    xmax, ymax = b[:, 2].max(), b[:, 3].max()
    side = max(xmax - xmin, ymax - ymin, 1e-6) * (1.0 + 2.0 * margin)
    cx, cy = (xmin + xmax) / 2.0, (ymin + ymax) / 2.0
    half = side / 2.0
    return (cx - half, cx + half, cy - half, cy + half)


__all__ = [
    "Canvas",
    "DrawBatch",
    "bbox_of",
    "pyramid",
    "level_shapes",
    "prim_mask",
    "rasterize",
    "viewport_of",
    "N_LEVELS",
]
