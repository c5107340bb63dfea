"""The `varied` set: training targets that cover what users draw (strokes of width 1-6 px,
thin script-like loops, filled blobs, 2-3 disjoint parts)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
from ngpm_runtime.image.morphology import label
from ngpm_runtime.image.targets import Target, auto_start, resize_mask
from PIL import Image, ImageDraw

from ngpm_compiler.datasets.common import SUPERSAMPLE, DatasetError, Item, Points, Polygon, pen

VARIED_KINDS = ("stroke", "script", "blob", "parts")
VARIED_P = (0.35, 0.25, 0.15, 0.25)
MIN_WIDTH_PX, MAX_WIDTH_PX = 1.0, 6.0  # stroke widths at 50 x 50
Part = tuple[Points, list[Polygon], float]  # pen points, filled polygons, base width


def _blob_poly(rng: np.random.Generator, cx: float, cy: float, r: float) -> Polygon:
    """A smooth random filled blob: a circle with low-frequency radial noise."""
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    rad = np.ones_like(t)
    for k in (2, 3, 4):
        rad += rng.normal(0, 0.18 / k) * np.cos(k * t + rng.uniform(0, 2 * np.pi))
    rad = r * np.clip(rad, 0.5, 1.6)
    return [(cx + a * math.cos(b), cy + a * math.sin(b)) for a, b in zip(rad, t, strict=True)]


def _varied_part(rng: np.random.Generator, kind: str, s: float, scale: float) -> Part:
    """One part: (pen points, filled polygons, base width in pixels at 50 x 50)."""
    px = s / 50
    x, y = rng.uniform(0.25, 0.75) * s, rng.uniform(0.3, 0.85) * s
    theta = -math.pi / 2 + rng.normal(0, 0.6) if rng.random() < 0.6 else rng.uniform(-3.1, 3.1)
    if kind == "script":  # thin, long, loopy, like a cursive letter
        w = rng.uniform(MIN_WIDTH_PX, 2.2)
        pts = pen(
            rng, s, x, y, theta, w * px, rng.uniform(0.06, 0.16), rng.uniform(1.5, 3.5) * s * scale
        )
        return pts, [], w
    if kind == "blob":  # a filled blob, sometimes with a stroke growing out of it
        w = rng.uniform(2.0, MAX_WIDTH_PX)
        r = rng.uniform(0.12, 0.25) * s * math.sqrt(scale)
        polys = [_blob_poly(rng, x, y - r * 0.5, r)]
        pts = (
            pen(
                rng,
                s,
                x,
                y - r * 0.5,
                theta,
                w * px,
                rng.uniform(0.01, 0.06),
                rng.uniform(0.4, 1.0) * s * scale,
            )
            if rng.random() < 0.6
            else []
        )
        return pts, polys, w
    w = rng.uniform(MIN_WIDTH_PX, MAX_WIDTH_PX)
    pts = pen(
        rng,
        s,
        x,
        y,
        theta,
        w * px,
        rng.choice([rng.uniform(0.01, 0.04), rng.uniform(0.05, 0.12)]),
        rng.uniform(0.8, 2.4) * s * scale * (1.0 if w < 4 else 0.7),
    )
    return pts, [], w


def _draw_parts(parts: list[Part], size: int) -> list[np.ndarray]:
    """The mask of each part at the working size."""
    k = SUPERSAMPLE
    out = []
    for pts, polys, _ in parts:
        img = Image.new("L", (size * k,) * 2, 0)
        draw = ImageDraw.Draw(img)
        for px, py, pw in pts:
            r = max(pw, 1.0) * k / 2
            draw.ellipse((px * k - r, py * k - r, px * k + r, py * k + r), fill=255)
        for poly in polys:
            draw.polygon([(a * k, b * k) for a, b in poly], fill=255)
        out.append(resize_mask(np.asarray(img) >= 128, size))
    return out


def varied(rng: np.random.Generator, size: int = 50) -> tuple[Target, dict[str, Any]]:
    """One training target of the `varied` set and what it is made of ({"kind", "widths"
    (base stroke widths in pixels at 50 x 50, 1 to 6), "parts" (connected components)}).

    Kinds: "stroke" (one scribble of width 1-6 px), "script" (a thin loopy stroke, 1-2.2 px),
    "blob" (a filled blob, maybe with a stroke out of it), "parts" (2-3 disjoint strokes or
    blobs; the vine starts on the first)."""
    kind = str(rng.choice(VARIED_KINDS, p=VARIED_P))
    for _ in range(200):
        n_parts = int(rng.integers(2, 4)) if kind == "parts" else 1
        kinds = (
            [
                str(rng.choice(("stroke", "script", "blob"), p=(0.5, 0.3, 0.2)))
                for _ in range(n_parts)
            ]
            if kind == "parts"
            else [kind]
        )
        parts = [_varied_part(rng, k, float(size), 0.6 if n_parts > 1 else 1.0) for k in kinds]
        masks = _draw_parts(parts, size)
        mask = np.logical_or.reduce(masks)
        if not 0.02 <= mask.mean() <= 0.45 or int(label(mask).max()) != n_parts:
            continue
        if any(int(label(m).max()) != 1 for m in masks):
            continue
        pts = parts[0][0]
        if pts:
            x0, y0 = pts[0][0], pts[0][1]
            dx, dy = pts[min(4, len(pts) - 1)][0] - x0, pts[min(4, len(pts) - 1)][1] - y0
            norm = math.hypot(dx, dy) or 1.0
            start = (x0 / size, y0 / size, dx / norm, dy / norm)
        else:
            start = auto_start(masks[0])
        row, col = min(int(start[1] * size), size - 1), min(int(start[0] * size), size - 1)
        if not masks[0][row, col]:
            continue
        info = {"kind": kind, "widths": [round(float(p[2]), 3) for p in parts], "parts": n_parts}
        return Target(mask, start, "varied"), info
    raise DatasetError("varied generator failed 200 times in a row")  # pragma: no cover


def build_varied(count: int, seed: int, size: int, **_: object) -> Iterator[Item]:
    for i in range(count):
        target, info = varied(np.random.default_rng([seed, 7, i]), size)
        widths = ",".join(f"{w:.1f}" for w in info["widths"])
        yield target, f"varied {info['kind']} {i} (parts {info['parts']}, width px {widths})"
