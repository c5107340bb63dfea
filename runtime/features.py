"""Guide features per site visit (architecture.md section 6), vectorized over particles.

Row layout: `local` = [x, y (viewport -> [-1, 1]), heading mod 360 -> [-1, 1], sin, cos,
width, depth / derivation_length] + module parameters (site.arity) + prior arguments
(site.n_args()); then `target` (36) and `partial` (36): at each pyramid level (H, H/2, H/4,
H/8) the 3x3 cells around the turtle's pixel (row-major, top row first), -1 outside the image.
The turtle's pixel at a level of size (h, w) is (floor(v * h), floor(u * w)) with (u, v) its
normalized image position (u right, v down from ymax).
"""

from __future__ import annotations

import numpy as np
from ngpm_runtime.program import Program, Site
from ngpm_runtime.raster import N_LEVELS, Canvas, Viewport, pyramid

N_LOCAL_BASE = 7
N_WINDOW = 9 * N_LEVELS  # 36 per image


def _fit_columns(a: np.ndarray, n: int, k: int) -> np.ndarray:
    """(n, k) float64: `a` reshaped, truncated or zero-padded to k columns."""
    a = np.asarray(a, dtype=np.float64)
    if a.size == 0:
        return np.zeros((n, k))
    a = a.reshape(n, -1)
    if a.shape[1] == k:
        return a
    out = np.zeros((n, k))
    m = min(k, a.shape[1])
    out[:, :m] = a[:, :m]
    return out


def window_features(levels: list[np.ndarray], idx: np.ndarray | None,
                    u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(n, 36) 3x3 windows at every level; `levels[l]` is (N, h, w), or (h, w) if idx is None."""
    n = len(u)
    out = np.full((n, 9 * len(levels)), -1.0, dtype=np.float32)
    # non-finite or far-away positions read as outside everywhere
    u = np.clip(np.nan_to_num(u, nan=-10.0), -10.0, 10.0)
    v = np.clip(np.nan_to_num(v, nan=-10.0), -10.0, 10.0)
    off = np.arange(-1, 2)
    for lv, arr in enumerate(levels):
        h, w = arr.shape[-2:]
        if h == 0 or w == 0:
            continue
        rows = np.floor(v * h).astype(np.intp)[:, None] + off  # (n, 3)
        cols = np.floor(u * w).astype(np.intp)[:, None] + off
        ok = ((rows >= 0) & (rows < h))[:, :, None] & ((cols >= 0) & (cols < w))[:, None, :]
        r = np.clip(rows, 0, h - 1)[:, :, None]
        c = np.clip(cols, 0, w - 1)[:, None, :]
        vals = arr[r, c] if idx is None else arr[idx[:, None, None], r, c]
        out[:, 9 * lv:9 * lv + 9] = np.where(ok, vals, -1.0).reshape(n, 9)
    return out


class FeatureMaker:
    """Builds the float32 feature rows the guide networks read."""

    def __init__(self, program: Program, viewport: Viewport,
                 target_mask: np.ndarray | None) -> None:
        self.program = program
        self.viewport = tuple(float(x) for x in viewport)
        self.derivation_length = float(getattr(program, "derivation_length", 1) or 1)
        self.target_levels = (None if target_mask is None
                              else pyramid(np.asarray(target_mask, dtype=bool)))

    @staticmethod
    def n_local(site: Site) -> int:
        return N_LOCAL_BASE + int(site.arity) + int(site.n_args())

    def layout(self, site: Site) -> dict[str, slice]:
        """Column ranges of the feature groups for a site."""
        nl = self.n_local(site)
        return {"local": slice(0, nl), "target": slice(nl, nl + N_WINDOW),
                "partial": slice(nl + N_WINDOW, nl + 2 * N_WINDOW)}

    def n_features(self, site: Site) -> int:
        return self.n_local(site) + 2 * N_WINDOW

    def features(self, site: Site, canvas: Canvas | None, idx: np.ndarray, turtle: np.ndarray,
                 depth: np.ndarray, params: np.ndarray, prior_args: np.ndarray) -> np.ndarray:
        idx = np.asarray(idx, dtype=np.intp).reshape(-1)
        n = len(idx)
        turtle = np.asarray(turtle, dtype=np.float64).reshape(n, 4)
        x, y, heading, width = turtle.T
        xmin, xmax, ymin, ymax = self.viewport
        u = (x - xmin) / (xmax - xmin)
        v = (ymax - y) / (ymax - ymin)
        rad = np.radians(heading)
        base = np.stack([2.0 * u - 1.0, 1.0 - 2.0 * v, np.mod(heading, 360.0) / 180.0 - 1.0,
                         np.sin(rad), np.cos(rad), width,
                         np.asarray(depth, dtype=np.float64).reshape(n)
                         / self.derivation_length], axis=1)
        lay = self.layout(site)
        out = np.empty((n, self.n_features(site)), dtype=np.float32)
        out[:, :N_LOCAL_BASE] = base
        out[:, N_LOCAL_BASE:N_LOCAL_BASE + site.arity] = _fit_columns(params, n, site.arity)
        out[:, N_LOCAL_BASE + site.arity:lay["local"].stop] = _fit_columns(
            prior_args, n, site.n_args())
        if self.target_levels is None:
            out[:, lay["target"]] = 0.0
        else:
            out[:, lay["target"]] = window_features(self.target_levels, None, u, v)
        if canvas is None:
            out[:, lay["partial"]] = 0.0
        else:
            out[:, lay["partial"]] = window_features(canvas.levels, idx, u, v)
        return out
