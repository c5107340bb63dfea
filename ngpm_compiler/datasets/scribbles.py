"""The `scribbles` set: synthetic hand-drawn-looking strokes (training), each starting where
the stroke began."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
from ngpm_runtime.image.morphology import label
from ngpm_runtime.image.targets import Target, resize_mask
from PIL import Image, ImageDraw

from ngpm_compiler.datasets.common import SUPERSAMPLE, DatasetError, Item, ellipse_poly, pen


def scribble(rng: np.random.Generator, size: int = 50) -> Target:
    """One synthetic hand-drawn-looking stroke (plus optional blobs) and its exact start.

    The pen moves in half-pixel steps with a curvature that follows a mean-reverting random
    walk (low or high curvature, so some strokes loop and cross themselves), its width
    varies slowly around a thin, medium or thick base, it is steered back when it nears the
    border, and blobs (filled ellipses) may sit on the path. The start is the first pen
    position and heading.
    """
    for _ in range(50):
        target = _try_scribble(rng, size)
        if target is not None:
            return target
    raise DatasetError("scribble generator failed 50 times in a row")  # pragma: no cover


def _try_scribble(rng: np.random.Generator, size: int) -> Target | None:
    s = float(size)
    base_w = (
        rng.choice(
            [rng.uniform(1.8, 2.8), rng.uniform(2.8, 4.5), rng.uniform(4.5, 7.0)],
            p=[0.35, 0.4, 0.25],
        )
        * s
        / 50
    )
    sigma = rng.choice([rng.uniform(0.01, 0.04), rng.uniform(0.05, 0.12)], p=[0.5, 0.5])
    length = rng.uniform(0.9, 2.6) * s * (1.0 if base_w < 4.5 * s / 50 else 0.7)
    if rng.random() < 0.75:  # most strokes begin low and go up, like a plant
        x, y = rng.uniform(0.3, 0.7) * s, rng.uniform(0.75, 0.9) * s
        theta = -math.pi / 2 + rng.normal(0, 0.4)
    else:
        x, y = rng.uniform(0.25, 0.75) * s, rng.uniform(0.25, 0.75) * s
        theta = rng.uniform(-math.pi, math.pi)
    start = (x / s, y / s, math.cos(theta), math.sin(theta))
    pts = pen(rng, s, x, y, theta, base_w, sigma, length, margin=0.12, widths=(0.7, 1.3))
    blobs = []
    if rng.random() < 0.3:
        for _ in range(rng.integers(1, 3)):
            px, py, pw = pts[int(rng.integers(len(pts) // 3, len(pts)))]
            r = rng.uniform(1.2, 2.5) * max(pw, 2.0)
            blobs.append((px, py, r, r * rng.uniform(0.5, 1.0), rng.uniform(0, math.pi)))
    img = Image.new("L", (size * SUPERSAMPLE,) * 2, 0)
    draw = ImageDraw.Draw(img)
    k = SUPERSAMPLE
    for px, py, pw in pts:
        r = pw * k / 2
        draw.ellipse((px * k - r, py * k - r, px * k + r, py * k + r), fill=255)
    for bx, by, ra, rb, ang in blobs:
        draw.polygon(ellipse_poly(bx * k, by * k, ra * k, rb * k, ang), fill=255)
    mask = resize_mask(np.asarray(img) >= 128, size)
    frac = mask.mean()
    if not (0.03 <= frac <= 0.45) or label(mask).max() != 1:
        return None
    row, col = min(int(start[1] * size), size - 1), min(int(start[0] * size), size - 1)
    if not mask[row, col]:
        return None
    return Target(mask, start, "scribble")


def build_scribbles(count: int, seed: int, size: int, **_: object) -> Iterator[Item]:
    for i in range(count):
        yield scribble(np.random.default_rng([seed, i]), size), f"synthetic scribble {i}"
