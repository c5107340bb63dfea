"""Image likelihoods (architecture.md section 7), incremental over `DrawBatch`es.

Every likelihood keeps per-particle state arrays (indexed by the SMC with the resampling
indices) and returns, per draw, `new log-lik - previous log-lik` (the shape and circuit
updates are compiled kernels, ngpm_runtime.kernels; the functions here compute the same
values from scratch). State `ll` starts at 0, so
the first increment also carries the blank image's value and the sum of a particle's
increments is its log-likelihood from scratch (`full(image, bbox)`).

Sobel (both likelihoods): the standard 3x3 kernels [[1,0,-1],[2,0,-2],[1,0,-1]] and its
transpose, zero padding, gradient magnitude sqrt(gx^2 + gy^2), divided by 4 so that a straight
edge of a 0/1 image reads 1 (the reference's "edge pixels count 1.5 x filled ones").
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ngpm_runtime.errors import TargetError
from ngpm_runtime.geometry.turtle import Prim
from ngpm_runtime.image.raster import Canvas, DrawBatch, Viewport, as_viewport

SHAPE_SIGMA = 0.02
FLAT = 1.0 / 1.5
BOUNDS_SCALE = 0.001
CIRCUIT_TAU = 0.5
CIRCUIT_SIGMA = 0.01


def _sobel_valid(p: np.ndarray) -> np.ndarray:
    """Sobel magnitude / 4 of the interior of padded arrays (..., h+2, w+2) -> (..., h, w)."""
    p = np.asarray(p, dtype=np.float64)
    left, mid, right = p[..., :, :-2], p[..., :, 1:-1], p[..., :, 2:]
    # horizontal derivative (columns), smoothed over rows
    dx = right - left
    gx = dx[..., :-2, :] + 2.0 * dx[..., 1:-1, :] + dx[..., 2:, :]
    sm = left + 2.0 * mid + right
    gy = sm[..., 2:, :] - sm[..., :-2, :]
    out: np.ndarray = np.sqrt(gx * gx + gy * gy) / 4.0
    return out


def sobel(image: np.ndarray) -> np.ndarray:
    """Sobel gradient magnitude / 4 of an (..., H, W) image with zero padding."""
    img = np.asarray(image, dtype=np.float64)
    pad = [(0, 0)] * (img.ndim - 2) + [(1, 1), (1, 1)]
    return _sobel_valid(np.pad(img, pad))


def shape_weights(target_mask: np.ndarray) -> np.ndarray:
    """w(p): 1 where the target is empty, else flat + (1 - flat) * min(1, sobel(T))."""
    t = np.asarray(target_mask, dtype=bool)
    edge = np.minimum(sobel(t), 1.0)
    return np.where(t, FLAT + (1.0 - FLAT) * edge, 1.0)


def _blank_sim(w: np.ndarray, t: np.ndarray) -> tuple[float, float]:
    total = float(w.sum())
    sim0 = float(w[~t].sum()) / total
    if not 1.0 - sim0 > 0.0:
        raise TargetError("target mask is empty: shape likelihood needs filled pixels")
    return sim0, total


def similarity(image: np.ndarray, target_mask: np.ndarray) -> float:
    """Normalized weighted similarity (sim(I,T) - sim(blank,T)) / (1 - sim(blank,T))."""
    t = np.asarray(target_mask, dtype=bool)
    img = np.asarray(image).astype(bool)
    if img.shape != t.shape:
        raise ValueError(f"image {img.shape} and target {t.shape} differ in size")
    w = shape_weights(t)
    sim0, total = _blank_sim(w, t)
    sim = float(w[img == t].sum()) / total
    return (sim - sim0) / (1.0 - sim0)


def bounds_penalty(bbox: np.ndarray, viewport: Viewport) -> np.ndarray:
    """-(extraX/0.001)^2 - (extraY/0.001)^2 for boxes (..., 4) = (xmin, ymin, xmax, ymax).

    extraX is how far the box overhangs the viewport left plus right, over its width.
    A box of +-inf (nothing drawn yet) has no overhang.
    """
    b = np.asarray(bbox, dtype=np.float64)
    xmin, xmax, ymin, ymax = viewport
    with np.errstate(invalid="ignore"):
        ex = np.maximum(xmin - b[..., 0], 0.0) + np.maximum(b[..., 2] - xmax, 0.0)
        ey = np.maximum(ymin - b[..., 1], 0.0) + np.maximum(b[..., 3] - ymax, 0.0)
    empty = ~(b[..., 0] <= b[..., 2])
    ex = np.where(empty, 0.0, ex) / (xmax - xmin)
    ey = np.where(empty, 0.0, ey) / (ymax - ymin)
    return -((ex / BOUNDS_SCALE) ** 2) - (ey / BOUNDS_SCALE) ** 2


def shape_loglik(
    image: np.ndarray, target_mask: np.ndarray, bbox: np.ndarray, viewport: Viewport
) -> float:
    """Equation 1 from scratch: -(simNorm - 1)^2 / 0.02^2 + bounds terms."""
    s = similarity(image, target_mask)
    return float(-(((s - 1.0) / SHAPE_SIGMA) ** 2) + bounds_penalty(bbox, viewport))


def circuit_loglik(image: np.ndarray, bbox: np.ndarray, viewport: Viewport) -> float:
    """Equation 2 from scratch: log N(edge(I) * (1 - relerr(fill(I), tau)); 1, sigma) + bounds."""
    img = np.asarray(image, dtype=np.float64)
    edge = float(sobel(img).mean())
    fill = float(img.mean())
    return float(
        _circuit_value(np.float64(edge), np.float64(fill)) + bounds_penalty(bbox, viewport)
    )


def circuit_score(image: np.ndarray) -> float:
    """Equation 2's argument, edge(I) * (1 - |fill(I) - tau| / tau): 1 is the optimum, 0 a
    blank image (a circuit run's score, as similarity is a shape run's)."""
    img = np.asarray(image, dtype=np.float64)
    edge, fill = float(sobel(img).mean()), float(img.mean())
    return edge * (1.0 - abs(fill - CIRCUIT_TAU) / CIRCUIT_TAU)


def _circuit_value(edge: np.ndarray | np.float64, fill: np.ndarray | np.float64) -> np.ndarray:
    x = edge * (1.0 - np.abs(fill - CIRCUIT_TAU) / CIRCUIT_TAU)
    z = (x - 1.0) / CIRCUIT_SIGMA
    return -0.5 * z * z - math.log(CIRCUIT_SIGMA * math.sqrt(2.0 * math.pi))


def empty_bbox(n: int) -> np.ndarray:
    """n boxes holding nothing yet (+inf mins, -inf maxes)."""
    out = np.empty((n, 4))
    out[:, :2] = np.inf
    out[:, 2:] = -np.inf
    return out


@dataclass
class PrimBatch:
    """What a likelihood sees when the run has no canvas: who drew what."""

    idx: np.ndarray
    bbox: np.ndarray
    prims: list[Prim]


class Likelihood(Protocol):
    """What `smc()` asks of a likelihood (subclass it to inherit the defaults).

    - `needs_canvas`: True (default): `increment` gets raster's DrawBatch (with `.prims`) and
      the run's Canvas; False: a `PrimBatch` (idx, bbox, prims), and no canvas is drawn
      for it.
    - `start(n)`: per-particle state arrays; SMC reindexes every array at resampling.
    - `increment(state, canvas, batch)`: per listed particle, new log-lik minus previous.
    - `blank_loglik(height, width)`: log-likelihood of an empty drawing, charged to particles
      that end without drawing anything (increments only come with primitives); None
      (default) when it cannot say.
    - `settles`: True when `increment` follows a potential (any positive function of an
      unfinished drawing: SMC's intermediate targets) rather than the log-likelihood; then
      `settle(state, idx)` gives, for particles that just finished, log-likelihood minus
      potential so far (and makes them equal), which SMC adds to their weights: finished
      particles carry the likelihood itself, so the weights stay exact.
    """

    needs_canvas: bool = True
    settles: bool = False

    def start(self, n: int) -> dict[str, np.ndarray]: ...

    # Any: a Canvas and a DrawBatch with `needs_canvas`, else None and a PrimBatch
    def increment(self, state: dict[str, np.ndarray], canvas: Any, batch: Any) -> np.ndarray: ...

    def blank_loglik(self, height: int, width: int) -> float | None:
        return None

    def settle(self, state: dict[str, np.ndarray], idx: np.ndarray) -> np.ndarray:
        return np.zeros(len(idx))


def _kernels() -> Any:
    """The compiled kernels (ngpm_runtime.kernels), imported when a likelihood is made."""
    from ngpm_runtime import kernels

    return kernels


def _blank_value(full: Callable[[np.ndarray, np.ndarray], float], height: int, width: int) -> float:
    """`full` of an empty image with an empty box; NaN reads as zero likelihood."""
    blank = np.zeros((height, width), dtype=np.uint8)
    value = float(full(blank, np.array([np.inf, np.inf, -np.inf, -np.inf])))
    return value if not math.isnan(value) else -math.inf


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
        self._vp = np.array(self.viewport)
        self._k = _kernels()

    def start(self, n: int) -> dict[str, np.ndarray]:
        return {"sim": np.zeros(n), "bbox": empty_bbox(n), "ll": np.zeros(n)}

    def increment(
        self, state: dict[str, np.ndarray], canvas: Canvas, draw: DrawBatch
    ) -> np.ndarray:
        if canvas.image.shape[1:] != self.target.shape:
            raise TargetError(
                f"canvas {canvas.image.shape[1:]} and target {self.target.shape} differ in size"
            )
        k, pix = draw.hits(self.target.shape[1])
        delta: np.ndarray = self._k.shape_increment(
            state["sim"],
            state["bbox"],
            state["ll"],
            draw.idx,
            k,
            pix,
            self.gain_flat,
            draw.bbox,
            self._vp,
        )
        return delta

    def full(self, image: np.ndarray, bbox: np.ndarray) -> float:
        """Log-likelihood of one finished image from scratch."""
        return shape_loglik(image, self.target, bbox, self.viewport)

    def blank_loglik(self, height: int, width: int) -> float | None:
        return _blank_value(self.full, height, width)


class CircuitLikelihood(Likelihood):
    """The paper's equation 2: dense edges at about half fill (no target). An unfinished
    vine is weighed by equation 2 with its fill below half not counted against it (it can
    still grow to half): weighed by its fill, a vine that stopped early outweighed its
    growing siblings (the guide's small halt probability) and resampling copied it into
    every particle (experiments/notes/circuit_guide_retrain.md)."""

    needs_canvas = True
    settles = True

    def __init__(self, viewport: Viewport) -> None:
        self.viewport = as_viewport(viewport)
        self._vp = np.array(self.viewport)
        self._k = _kernels()

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
        delta: np.ndarray = self._k.circuit_increment(
            state["edge_sum"],
            state["filled"],
            state["bbox"],
            state["ll"],
            state["pot"],
            canvas.image,
            draw.idx,
            draw.y0,
            draw.x0,
            draw.new,
            draw.bbox,
            self._vp,
        )
        return delta

    def full(self, image: np.ndarray, bbox: np.ndarray) -> float:
        return circuit_loglik(image, bbox, self.viewport)

    def settle(self, state: dict[str, np.ndarray], idx: np.ndarray) -> np.ndarray:
        ll, pot = state["ll"], state["pot"]
        out: np.ndarray = ll[idx] - pot[idx]
        pot[idx] = ll[idx]
        return out

    def blank_loglik(self, height: int, width: int) -> float | None:
        return _blank_value(self.full, height, width)


class NullLikelihood(Likelihood):
    """Forward sampling: every increment is 0 (works on any batch with `.idx`); `smc()`
    treats it as no likelihood at all (no canvas, nothing computed)."""

    needs_canvas = False

    def start(self, n: int) -> dict[str, np.ndarray]:
        return {}

    def increment(
        self, state: dict[str, np.ndarray], canvas: Canvas, draw: DrawBatch
    ) -> np.ndarray:
        return np.zeros(len(draw.idx))

    def full(self, image: np.ndarray, bbox: np.ndarray) -> float:
        return 0.0

    def blank_loglik(self, height: int, width: int) -> float | None:
        return 0.0
