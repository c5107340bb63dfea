"""What the dataset families share: their errors and warnings, the `Item` they yield, the
supersampling of drawings, and the pen strokes and ellipses they draw with."""

from __future__ import annotations

import math

import numpy as np
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.image.targets import Target

SUPERSAMPLE = 4  # drawings are made at 4x the working size, then area-averaged


class DatasetError(NgpmError):
    """A dataset cannot be built (unknown name, unreadable font, wrong directory)."""


class DatasetWarning(UserWarning):
    """A source item was skipped during a build."""


Item = tuple[Target, str]  # a target (name not final yet) and where it came from
Points = list[tuple[float, float, float]]  # pen positions (x, y, width) of a stroke
Polygon = list[tuple[float, float]]


def ellipse_poly(cx: float, cy: float, ra: float, rb: float, ang: float, n: int = 48) -> Polygon:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ex, ey = ra * np.cos(t), rb * np.sin(t)
    c, s = math.cos(ang), math.sin(ang)
    return [(cx + c * a - s * b, cy + s * a + c * b) for a, b in zip(ex, ey, strict=True)]


def pen(
    rng: np.random.Generator,
    s: float,
    x: float,
    y: float,
    theta: float,
    base_w: float,
    sigma: float,
    length: float,
    margin: float = 0.1,
    widths: tuple[float, float] = (0.85, 1.15),
) -> Points:
    """Pen positions (x, y, width) of one stroke: curvature a mean-reverting random walk,
    width varying slowly around `base_w` (within `widths` x base_w), steered back toward the
    center within `margin` x s of the border."""
    step, kappa, wmul = 0.5, rng.normal(0, 3 * sigma), 1.0
    margin = margin * s
    pts = [(x, y, base_w)]
    for _ in range(int(length / step)):
        kappa += -kappa * step / 8.0 + sigma * math.sqrt(step) * rng.normal()
        theta += kappa * step
        if min(x, y, s - x, s - y) < margin:
            to_c = math.atan2(s / 2 - y, s / 2 - x)
            theta += 0.25 * math.remainder(to_c - theta, 2 * math.pi)
            kappa *= 0.5
        x += step * math.cos(theta)
        y += step * math.sin(theta)
        wmul = float(np.clip(wmul + 0.03 * rng.normal(), *widths))
        pts.append((x, y, base_w * wmul))
    return pts
