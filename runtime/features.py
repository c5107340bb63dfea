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
from ngpm_runtime.errors import TargetError
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


def _unit(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # non-finite or far-away positions read as outside everywhere
    u = np.nan_to_num(np.asarray(u, dtype=np.float64), nan=-10.0, posinf=10.0, neginf=-10.0)
    v = np.nan_to_num(np.asarray(v, dtype=np.float64), nan=-10.0, posinf=10.0, neginf=-10.0)
    return np.minimum(np.maximum(u, -10.0), 10.0), np.minimum(np.maximum(v, -10.0), 10.0)


def window_cells(shapes: list[tuple[int, int]], u: np.ndarray, v: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """3x3 windows at every level: cell index within its level (n, L, 3, 3), inside mask."""
    u, v = _unit(u, v)
    hs = np.array([s[0] for s in shapes], dtype=np.intp)
    ws = np.array([s[1] for s in shapes], dtype=np.intp)
    off = np.arange(-1, 2)
    rows = np.floor(v[:, None] * hs).astype(np.intp)[:, :, None] + off  # (n, L, 3)
    cols = np.floor(u[:, None] * ws).astype(np.intp)[:, :, None] + off
    hb, wb = hs[:, None], ws[:, None]
    ok = ((rows >= 0) & (rows < hb))[..., None] & ((cols >= 0) & (cols < wb))[..., None, :]
    rows = np.minimum(np.maximum(rows, 0), np.maximum(hb - 1, 0))
    cols = np.minimum(np.maximum(cols, 0), np.maximum(wb - 1, 0))
    cell = rows[..., None] * wb[..., None] + cols[..., None, :]
    return cell, ok


def window_features(levels: list[np.ndarray], idx: np.ndarray | None,
                    u: np.ndarray, v: np.ndarray,
                    cells: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(n, 9 L) 3x3 windows at every level, -1 outside; `levels[l]` is (N, h, w) read at
    particles `idx`, or (h, w) when idx is None. `cells` = window_cells(...) if known."""
    shapes = [a.shape[-2:] for a in levels]
    cell, ok = window_cells(shapes, u, v) if cells is None else cells
    n = cell.shape[0]
    vals = np.empty(cell.shape, dtype=np.float32)
    for lv, arr in enumerate(levels):
        h, w = shapes[lv]
        if h == 0 or w == 0:
            continue
        flat = cell[:, lv] if idx is None else cell[:, lv] + (idx * (h * w))[:, None, None]
        vals[:, lv] = arr.reshape(-1)[flat]
    return np.where(ok, vals, np.float32(-1.0)).reshape(n, -1)


class FeatureMaker:
    """Builds the float32 feature rows the guide networks read."""

    def __init__(self, program: Program, viewport: Viewport,
                 target_mask: np.ndarray | None) -> None:
        self.program = program
        self.viewport = tuple(float(x) for x in viewport)
        self.derivation_length = float(getattr(program, "derivation_length", 1) or 1)
        self.target_levels = (None if target_mask is None
                              else pyramid(np.asarray(target_mask, dtype=bool)))

    def _shape(self, canvas: Canvas | None) -> tuple[int, int]:
        if canvas is not None:
            if (self.target_levels is not None
                    and self.target_levels[0].shape != canvas.image.shape[1:]):
                raise TargetError(f"canvas {canvas.image.shape[1:]} and target "
                                  f"{self.target_levels[0].shape} differ in size")
            return canvas.height, canvas.width
        if self.target_levels is not None:
            return self.target_levels[0].shape
        return (0, 0)

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
        shapes = [(h >> lv, w >> lv) for lv in range(N_LEVELS)
                  for h, w in [self._shape(canvas)]]
        cells = window_cells(shapes, u, v)
        if self.target_levels is None:
            out[:, lay["target"]] = 0.0
        else:
            out[:, lay["target"]] = window_features(self.target_levels, None, u, v, cells)
        if canvas is None:
            out[:, lay["partial"]] = 0.0
        else:
            out[:, lay["partial"]] = window_features(canvas.levels, idx, u, v, cells)
        return out
