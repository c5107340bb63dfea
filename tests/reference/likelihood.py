"""The numpy likelihood updates the compiled kernels replaced (ngpm_runtime/kernels.py),
kept as the tests' reference: `ShapeLikelihood` and `CircuitLikelihood` increment as the
runtime's did before numba (git history: runtime/ngpm_runtime/inference/likelihood.py)."""

from __future__ import annotations

import numpy as np
from ngpm_runtime.errors import TargetError
from ngpm_runtime.image.raster import Canvas, DrawBatch, Viewport, as_viewport
from ngpm_runtime.inference.likelihood import (
    CIRCUIT_TAU,
    SHAPE_SIGMA,
    Likelihood,
    _blank_sim,
    _circuit_value,
    bounds_penalty,
    empty_bbox,
    shape_weights,
)


def union_bbox(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Union of boxes (..., 4) in (xmin, ymin, xmax, ymax) order."""
    return np.concatenate(
        [np.minimum(a[..., :2], b[..., :2]), np.maximum(a[..., 2:], b[..., 2:])], axis=-1
    )


class ShapeLikelihood(Likelihood):
    """The paper's equation 1 against a target mask (H, W) bool on a same-size canvas."""

    needs_canvas = True

    def __init__(self, target_mask: np.ndarray, viewport: Viewport) -> None:
        t = np.asarray(target_mask, dtype=bool)
        if t.ndim != 2:
            raise TargetError(f"target mask must be 2D, got shape {t.shape}")
        self.target = t
        self.viewport = as_viewport(viewport)
        w = shape_weights(t)
        self.sim_blank, total = _blank_sim(w, t)
        # gain of covering pixel p, in normalized-similarity units
        self.gain = w * (2.0 * t - 1.0) / total / (1.0 - self.sim_blank)
        self.gain_flat = self.gain.reshape(-1)

    def start(self, n: int) -> dict[str, np.ndarray]:
        return {"sim": np.zeros(n), "bbox": empty_bbox(n), "ll": np.zeros(n)}

    def increment(
        self, state: dict[str, np.ndarray], canvas: Canvas, draw: DrawBatch
    ) -> np.ndarray:
        if canvas.image.shape[1:] != self.target.shape:
            raise TargetError(
                f"canvas {canvas.image.shape[1:]} and target {self.target.shape} differ in size"
            )
        idx = draw.idx
        k, pix = draw.hits(self.target.shape[1])
        dsim = np.bincount(k, weights=self.gain_flat[pix], minlength=len(idx))
        sim = state["sim"][idx] + dsim
        bbox = union_bbox(state["bbox"][idx], draw.bbox)
        ll = -(((sim - 1.0) / SHAPE_SIGMA) ** 2) + bounds_penalty(bbox, self.viewport)
        delta: np.ndarray = ll - state["ll"][idx]
        state["sim"][idx] = sim
        state["bbox"][idx] = bbox
        state["ll"][idx] = ll
        return delta


# Sobel magnitude / 4 of a 0/1 image, by the integer gradients (gx, gy) in [-4, 4]^2
_GRAD = np.arange(-4, 5)
_MAG_LUT = (np.sqrt(_GRAD[:, None] ** 2 + _GRAD[None, :] ** 2) / 4.0).reshape(-1)


def _edge_sum_codes(p: np.ndarray) -> np.ndarray:
    """LUT codes (n, h, w) of the Sobel gradients of 0/1 int16 patches (n, h+2, w+2)."""
    left, mid, right = p[:, :, :-2], p[:, :, 1:-1], p[:, :, 2:]
    dx = right - left
    gx = dx[:, :-2] + 2 * dx[:, 1:-1] + dx[:, 2:]
    sm = left + 2 * mid + right
    gy = sm[:, 2:] - sm[:, :-2]
    out: np.ndarray = (gx + 4) * 9 + (gy + 4)
    return out


def _edge_change(
    image: np.ndarray, idx: np.ndarray, y0: np.ndarray, x0: np.ndarray, new: np.ndarray
) -> np.ndarray:
    """Change of each canvas's Sobel magnitude sum caused by its `new` pixels (already drawn).

    Only the window plus a 1-pixel ring can change; that needs a 2-pixel margin of input.
    """
    _, h, w = image.shape
    ky, kx = new.shape[1:]
    rows = y0[:, None] + np.arange(-2, ky + 2)  # (n, ky+4)
    cols = x0[:, None] + np.arange(-2, kx + 2)
    rin = (rows >= 0) & (rows < h)
    cin = (cols >= 0) & (cols < w)
    flat = (idx[:, None] * h + np.clip(rows, 0, h - 1))[:, :, None] * w + np.clip(cols, 0, w - 1)[
        :, None, :
    ]
    after = image.reshape(-1)[flat].astype(np.int16)
    after *= rin[:, :, None] & cin[:, None, :]
    before = after.copy()
    before[:, 2 : 2 + ky, 2 : 2 + kx] -= new
    inner = rin[:, 1:-1, None] & cin[:, None, 1:-1]
    diff = _MAG_LUT[_edge_sum_codes(after)] - _MAG_LUT[_edge_sum_codes(before)]
    out: np.ndarray = (diff * inner).sum(axis=(1, 2))
    return out


class CircuitLikelihood(Likelihood):
    """The paper's equation 2: dense edges at about half fill (no target)."""

    needs_canvas = True

    def __init__(self, viewport: Viewport) -> None:
        self.viewport = as_viewport(viewport)

    def start(self, n: int) -> dict[str, np.ndarray]:
        return {
            "edge_sum": np.zeros(n),
            "filled": np.zeros(n),
            "bbox": empty_bbox(n),
            "ll": np.zeros(n),
            "pot": np.zeros(n),
        }

    def increment(
        self, state: dict[str, np.ndarray], canvas: Canvas, draw: DrawBatch
    ) -> np.ndarray:
        idx = draw.idx
        h, w = canvas.height, canvas.width
        d_edge = np.zeros(len(idx))
        changed = np.flatnonzero(draw.new.any(axis=(1, 2)))
        if changed.size:
            d_edge[changed] = _edge_change(
                canvas.image, idx[changed], draw.y0[changed], draw.x0[changed], draw.new[changed]
            )
        edge_sum = state["edge_sum"][idx] + d_edge
        filled = state["filled"][idx] + draw.new.sum(axis=(1, 2))
        bbox = union_bbox(state["bbox"][idx], draw.bbox)
        npx = float(h * w)
        edge, fill = edge_sum / npx, filled / npx
        bounds = bounds_penalty(bbox, self.viewport)
        ll = _circuit_value(edge, fill) + bounds
        # the potential: a fill below tau not counted against an unfinished vine
        pot = _circuit_value(edge, np.maximum(fill, CIRCUIT_TAU)) + bounds
        delta: np.ndarray = pot - state["pot"][idx]
        state["edge_sum"][idx] = edge_sum
        state["filled"][idx] = filled
        state["bbox"][idx] = bbox
        state["ll"][idx] = ll
        state["pot"][idx] = pot
        return delta
