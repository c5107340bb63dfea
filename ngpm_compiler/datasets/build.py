"""Target datasets: synthetic scribbles (training), font glyphs and silhouettes (testing).

Every builder yields `(Target, source)` pairs; `build_dataset` writes them as
`NAME_0000.png` + `NAME_0000.txt` (the sidecar) plus `index.json`, one file at a time
(atomic writes), skipping files that already exist, so an interrupted build resumes.
Nothing is downloaded: fonts and silhouettes come from files on this machine.
"""

from __future__ import annotations

import io
import json
import math
import os
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from ngpm_runtime.errors import NgpmError, TargetError
from ngpm_runtime.files import atomic_write
from ngpm_runtime.image.morphology import label
from ngpm_runtime.image.targets import (
    IMAGE_SUFFIXES,
    Target,
    auto_start,
    check_mask,
    image_to_mask,
    read_image,
    read_sidecar,
    resize_mask,
    save_target,
    sidecar_path,
)
from PIL import Image, ImageDraw, ImageFont

SUPERSAMPLE = 4  # drawings are made at 4x the working size, then area-averaged
MIN_GLYPH_FRACTION = 0.04  # a glyph must cover at least 4% of the image (100 px at 50 x 50)
FIT_MARGIN = 0.1  # silhouettes are cropped and framed with 10% margin on each side


class DatasetError(NgpmError):
    """A dataset cannot be built (unknown name, unreadable font, wrong directory)."""


class DatasetWarning(UserWarning):
    """A source item was skipped during a build."""


Item = tuple[Target, str]  # a target (name not final yet) and where it came from


@dataclass(frozen=True)
class DatasetSpec:
    name: str
    description: str
    default_count: int | None  # None: every item the source provides
    builder: Callable[..., Iterator[Item]]


# --- scribbles ---------------------------------------------------------------------------


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
    base_w = rng.choice([rng.uniform(1.8, 2.8), rng.uniform(2.8, 4.5), rng.uniform(4.5, 7.0)],
                        p=[0.35, 0.4, 0.25]) * s / 50
    sigma = rng.choice([rng.uniform(0.01, 0.04), rng.uniform(0.05, 0.12)], p=[0.5, 0.5])
    length = rng.uniform(0.9, 2.6) * s * (1.0 if base_w < 4.5 * s / 50 else 0.7)
    if rng.random() < 0.75:  # most strokes begin low and go up, like a plant
        x, y = rng.uniform(0.3, 0.7) * s, rng.uniform(0.75, 0.9) * s
        theta = -math.pi / 2 + rng.normal(0, 0.4)
    else:
        x, y = rng.uniform(0.25, 0.75) * s, rng.uniform(0.25, 0.75) * s
        theta = rng.uniform(-math.pi, math.pi)
    start = (x / s, y / s, math.cos(theta), math.sin(theta))
    pts = _pen(rng, s, x, y, theta, base_w, sigma, length, margin=0.12, widths=(0.7, 1.3))
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
        draw.polygon(_ellipse_poly(bx * k, by * k, ra * k, rb * k, ang), fill=255)
    mask = resize_mask(np.asarray(img) >= 128, size)
    frac = mask.mean()
    if not (0.03 <= frac <= 0.45) or label(mask).max() != 1:
        return None
    row, col = min(int(start[1] * size), size - 1), min(int(start[0] * size), size - 1)
    if not mask[row, col]:
        return None
    return Target(mask, start, "scribble")


def _ellipse_poly(cx: float, cy: float, ra: float, rb: float, ang: float,
                  n: int = 48) -> list[tuple[float, float]]:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ex, ey = ra * np.cos(t), rb * np.sin(t)
    c, s = math.cos(ang), math.sin(ang)
    return [(cx + c * a - s * b, cy + s * a + c * b) for a, b in zip(ex, ey, strict=True)]


def build_scribbles(count: int, seed: int, size: int, **_: object) -> Iterator[Item]:
    for i in range(count):
        yield scribble(np.random.default_rng([seed, i]), size), f"synthetic scribble {i}"


# --- varied strokes (training targets that cover what users draw) -------------------------

VARIED_KINDS = ("stroke", "script", "blob", "parts")
VARIED_P = (0.35, 0.25, 0.15, 0.25)
MIN_WIDTH_PX, MAX_WIDTH_PX = 1.0, 6.0  # stroke widths at 50 x 50


def _pen(rng: np.random.Generator, s: float, x: float, y: float, theta: float, base_w: float,
         sigma: float, length: float, margin: float = 0.1,
         widths: tuple[float, float] = (0.85, 1.15)) -> list[tuple[float, float, float]]:
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


def _blob_poly(rng: np.random.Generator, cx: float, cy: float, r: float
               ) -> list[tuple[float, float]]:
    """A smooth random filled blob: a circle with low-frequency radial noise."""
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    rad = np.ones_like(t)
    for k in (2, 3, 4):
        rad += rng.normal(0, 0.18 / k) * np.cos(k * t + rng.uniform(0, 2 * np.pi))
    rad = r * np.clip(rad, 0.5, 1.6)
    return [(cx + a * math.cos(b), cy + a * math.sin(b)) for a, b in zip(rad, t, strict=True)]


def _varied_part(rng: np.random.Generator, kind: str, s: float, scale: float
                 ) -> tuple[list[tuple[float, float, float]], list[list[tuple[float, float]]],
                            float]:
    """One part: (pen points, filled polygons, base width in pixels at 50 x 50)."""
    px = s / 50
    x, y = rng.uniform(0.25, 0.75) * s, rng.uniform(0.3, 0.85) * s
    theta = -math.pi / 2 + rng.normal(0, 0.6) if rng.random() < 0.6 else rng.uniform(-3.1, 3.1)
    if kind == "script":  # thin, long, loopy, like a cursive letter
        w = rng.uniform(MIN_WIDTH_PX, 2.2)
        pts = _pen(rng, s, x, y, theta, w * px, rng.uniform(0.06, 0.16),
                   rng.uniform(1.5, 3.5) * s * scale)
        return pts, [], w
    if kind == "blob":  # a filled blob, sometimes with a stroke growing out of it
        w = rng.uniform(2.0, MAX_WIDTH_PX)
        r = rng.uniform(0.12, 0.25) * s * math.sqrt(scale)
        polys = [_blob_poly(rng, x, y - r * 0.5, r)]
        pts = (_pen(rng, s, x, y - r * 0.5, theta, w * px, rng.uniform(0.01, 0.06),
                    rng.uniform(0.4, 1.0) * s * scale) if rng.random() < 0.6 else [])
        return pts, polys, w
    w = rng.uniform(MIN_WIDTH_PX, MAX_WIDTH_PX)
    pts = _pen(rng, s, x, y, theta, w * px, rng.choice([rng.uniform(0.01, 0.04),
                                                         rng.uniform(0.05, 0.12)]),
               rng.uniform(0.8, 2.4) * s * scale * (1.0 if w < 4 else 0.7))
    return pts, [], w


def _draw_parts(parts: list[tuple[list, list, float]], size: int) -> list[np.ndarray]:
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


def varied(rng: np.random.Generator, size: int = 50) -> tuple[Target, dict]:
    """One training target of the `varied` set and what it is made of ({"kind", "widths"
    (base stroke widths in pixels at 50 x 50, 1 to 6), "parts" (connected components)}).

    Kinds: "stroke" (one scribble of width 1-6 px), "script" (a thin loopy stroke, 1-2.2 px),
    "blob" (a filled blob, maybe with a stroke out of it), "parts" (2-3 disjoint strokes or
    blobs; the vine starts on the first)."""
    kind = str(rng.choice(VARIED_KINDS, p=VARIED_P))
    for _ in range(200):
        n_parts = int(rng.integers(2, 4)) if kind == "parts" else 1
        kinds = ([str(rng.choice(("stroke", "script", "blob"), p=(0.5, 0.3, 0.2)))
                  for _ in range(n_parts)] if kind == "parts" else [kind])
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
        info = {"kind": kind, "widths": [round(float(p[2]), 3) for p in parts],
                "parts": n_parts}
        return Target(mask, start, "varied"), info
    raise DatasetError("varied generator failed 200 times in a row")  # pragma: no cover


def build_varied(count: int, seed: int, size: int, **_: object) -> Iterator[Item]:
    for i in range(count):
        target, info = varied(np.random.default_rng([seed, 7, i]), size)
        widths = ",".join(f"{w:.1f}" for w in info["widths"])
        yield target, f"varied {info['kind']} {i} (parts {info['parts']}, width px {widths})"


# --- glyphs ------------------------------------------------------------------------------

GLYPH_RANGES = ((0x21, 0x7E), (0xC0, 0x17F), (0x391, 0x3C9), (0x410, 0x44F))


def default_font() -> Path:
    """DejaVu Sans Bold, shipped with matplotlib."""
    import matplotlib

    return Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans-Bold.ttf"


def font_codepoints(font_path: Path) -> list[int]:
    """Code points in GLYPH_RANGES that the font maps to a glyph, ascending."""
    from fontTools.ttLib import TTFont

    try:
        cmap = TTFont(str(font_path), lazy=True).getBestCmap() or {}
    except Exception as err:  # fontTools raises many kinds on a bad file
        raise DatasetError(f"cannot read font {font_path}: {err}") from None
    return [c for lo, hi in GLYPH_RANGES for c in range(lo, hi + 1)
            if c in cmap and cmap[c] not in (".notdef", "space")]


def render_glyph(font: ImageFont.FreeTypeFont, char: str, size: int) -> np.ndarray:
    """Mask of one glyph at a fixed scale: the frame is the font's ascent + descent (plus 8%),
    the glyph sits on the baseline and is centered horizontally; glyphs wider than the frame
    are padded to a square, which shrinks them."""
    ascent, descent = font.getmetrics()
    side = int(round((ascent + descent) * 1.08))
    left, top, right, bottom = font.getbbox(char, anchor="ls")
    width = max(side, right - left + 4)
    img = Image.new("L", (width, side), 0)
    base_y = (side - (ascent + descent)) // 2 + ascent
    x = (width - (right - left)) / 2 - left
    ImageDraw.Draw(img).text((x, base_y), char, font=font, fill=255, anchor="ls")
    mask = np.asarray(img) >= 128
    h, w = mask.shape
    square = np.zeros((w, w), dtype=bool)
    square[(w - h) // 2:(w - h) // 2 + h] = mask
    return resize_mask(square, size)


def glyph_ok(mask: np.ndarray) -> str | None:
    """None when the glyph is usable, else why not (the paper's filter: one connected
    component, 8-connectivity, and enough pixels)."""
    if mask.mean() < MIN_GLYPH_FRACTION:
        return f"fewer than {MIN_GLYPH_FRACTION:.0%} of the pixels"
    n = int(label(mask).max())
    if n != 1:
        return f"{n} connected components"
    return None


def build_glyphs(count: int | None, seed: int, size: int, font: str | os.PathLike | None = None,
                 **_: object) -> Iterator[Item]:
    font_path = Path(font) if font is not None else default_font()
    if not font_path.is_file():
        raise DatasetError(f"font file {font_path} does not exist")
    codes = font_codepoints(font_path)
    try:
        face = ImageFont.truetype(str(font_path), size * SUPERSAMPLE)
    except OSError as err:
        raise DatasetError(f"cannot read font {font_path}: {err}") from None
    made = 0
    for code in codes:
        if count is not None and made >= count:
            return
        mask = render_glyph(face, chr(code), size)
        if glyph_ok(mask) is not None:
            continue
        made += 1
        yield Target(mask, auto_start(mask), "glyph"), f"{font_path.name} U+{code:04X} {chr(code)}"


# --- silhouettes -------------------------------------------------------------------------


def fit_mask(mask: np.ndarray, size: int, margin: float = FIT_MARGIN,
             start: tuple[float, float, float, float] | None = None,
             ) -> tuple[np.ndarray, tuple[float, float, float, float] | None]:
    """Crop to the shape's bounding box, frame it in a square with `margin` on each side
    (aspect kept), resize to size x size; a start point moves with the shape."""
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        raise TargetError("no shape")
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    crop = mask[r0:r1, c0:c1]
    side = int(math.ceil(max(crop.shape) / (1 - 2 * margin)))
    oy, ox = (side - crop.shape[0]) // 2, (side - crop.shape[1]) // 2
    square = np.zeros((side, side), dtype=bool)
    square[oy:oy + crop.shape[0], ox:ox + crop.shape[1]] = crop
    if start is not None:
        h, w = mask.shape
        x, y, dx, dy = start
        sx = float(np.clip((x * w - c0 + ox) / side, 0, 1))
        sy = float(np.clip((y * h - r0 + oy) / side, 0, 1))
        start = (sx, sy, dx, dy)
    return resize_mask(square, size), start


def drop_specks(mask: np.ndarray, fraction: float = 0.02) -> np.ndarray:
    """Remove connected components smaller than `fraction` of the foreground."""
    labels = label(mask)
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    keep = counts >= fraction * counts.sum()
    keep[0] = False
    return keep[labels]


def silhouette_from_image(path: Path, size: int, polarity: str = "auto") -> Target:
    """A silhouette target from a user image: mask, specks removed, fitted with a margin;
    its sidecar's start when it has one, else the automatic start."""
    img = read_image(path)
    mask = drop_specks(image_to_mask(img, polarity, str(path)))
    side = sidecar_path(path)
    start = read_sidecar(side) if side.is_file() else None
    fitted, start = fit_mask(mask, size, start=start)
    check_mask(fitted, str(path))
    return Target(fitted, start if start is not None else auto_start(fitted), path.stem)


def _shape_parts(kind: str, rng: np.random.Generator) -> list[tuple]:
    """Primitives of a procedural silhouette in unit coordinates (y down), jittered:
    ("e", cx, cy, rx, ry, angle) ellipses, ("p", [(x, y), ...]) polygons,
    ("l", [(x, y), ...], width) thick polylines.

    Long because it is a table of shape recipes, one branch per kind."""
    def j(v: float, amount: float = 0.06) -> float:
        return float(v * (1 + amount * rng.normal()))

    def legs(xs: tuple[float, ...], top: float, bottom: float, width: float) -> list[tuple]:
        return [("l", [(x, top), (x + 0.01, bottom)], width) for x in xs]

    if kind == "cat":
        hx, hy = j(0.5, 0.02), j(0.36, 0.05)
        return [
            ("e", 0.5, 0.66, j(0.2), j(0.25), 0.0),
            ("e", hx, hy, j(0.13), j(0.12), 0.0),
            ("p", [(hx - 0.12, hy - 0.03), (hx - 0.1, hy - j(0.2)), (hx - 0.02, hy - 0.09)]),
            ("p", [(hx + 0.12, hy - 0.03), (hx + 0.1, hy - j(0.2)), (hx + 0.02, hy - 0.09)]),
            ("l", [(0.66, 0.86), (j(0.82), 0.8), (j(0.86), j(0.62)), (0.8, 0.5)], j(0.045)),
        ]
    if kind == "rabbit":
        return [
            ("e", 0.5, 0.68, j(0.19), j(0.2), 0.0),
            ("e", 0.5, 0.42, j(0.12), j(0.11), 0.0),
            ("e", 0.45, 0.2, j(0.04), j(0.14), -0.15),
            ("e", 0.56, 0.2, j(0.04), j(0.14), 0.2),
            ("e", 0.69, 0.8, j(0.06), j(0.06), 0.0),
            ("e", 0.43, 0.87, j(0.1), 0.04, 0.0),
        ]
    if kind == "bird":
        return [
            ("e", 0.47, 0.5, j(0.23), j(0.14), j(-0.25)),
            ("e", 0.68, 0.32, j(0.1), j(0.1), 0.0),
            ("p", [(0.76, 0.29), (j(0.9), 0.33), (0.76, 0.36)]),
            ("p", [(0.28, 0.52), (0.08, j(0.62)), (0.14, j(0.72)), (0.34, 0.6)]),
            *legs((0.44, 0.52), 0.62, 0.82, 0.03),
        ]
    if kind == "fish":
        return [
            ("e", 0.45, 0.5, j(0.28), j(0.15), 0.0),
            ("p", [(0.68, 0.5), (0.88, j(0.32)), (0.84, 0.5), (0.88, j(0.68))]),
            ("p", [(0.35, 0.4), (0.47, j(0.25)), (0.55, 0.4)]),
        ]
    if kind == "dog":
        return [
            ("e", 0.48, 0.5, j(0.25), j(0.12), 0.0),
            ("e", 0.76, 0.36, j(0.09), j(0.09), 0.0),
            ("e", 0.84, 0.4, j(0.08), 0.05, 0.1),
            ("e", 0.72, 0.36, 0.04, j(0.1), 0.4),
            *legs((0.3, 0.4, 0.56, 0.66), 0.55, 0.8, j(0.06)),
            ("l", [(0.24, 0.46), (0.16, j(0.34))], 0.04),
        ]
    if kind == "turtle":
        return [
            ("e", 0.48, 0.52, j(0.28), j(0.18), 0.0),
            ("e", 0.8, 0.5, j(0.08), j(0.06), 0.0),
            ("e", 0.3, 0.66, 0.06, j(0.07), 0.4),
            ("e", 0.66, 0.66, 0.06, j(0.07), -0.4),
            ("p", [(0.2, 0.5), (j(0.12), 0.56), (0.22, 0.58)]),
        ]
    if kind == "snail":
        return [
            ("e", 0.52, 0.45, j(0.22), j(0.22), 0.0),
            ("e", 0.5, 0.7, j(0.36), 0.07, 0.0),
            ("l", [(0.8, 0.68), (0.86, j(0.42))], 0.03),
            ("l", [(0.78, 0.68), (0.76, j(0.44))], 0.03),
        ]
    if kind == "tree":
        return [
            ("l", [(0.5, 0.92), (0.5, 0.5)], j(0.1)),
            ("e", 0.5, j(0.35), j(0.2), j(0.2), 0.0),
            ("e", j(0.34), 0.45, j(0.14), j(0.13), 0.0),
            ("e", j(0.66), 0.45, j(0.14), j(0.13), 0.0),
        ]
    if kind == "mushroom":
        return [
            ("p", [(0.42, 0.9), (0.44, 0.45), (0.56, 0.45), (0.58, 0.9)]),
            ("e", 0.5, 0.45, j(0.32), j(0.22), 0.0),
        ]
    if kind == "cactus":
        return [
            ("l", [(0.5, 0.9), (0.5, 0.15)], j(0.13)),
            ("l", [(0.5, 0.6), (0.3, 0.6), (0.3, j(0.35))], j(0.09)),
            ("l", [(0.5, 0.5), (0.7, 0.5), (0.7, j(0.28))], j(0.09)),
        ]
    if kind == "duck":
        return [
            ("e", 0.48, 0.62, j(0.28), j(0.15), 0.0),
            ("e", 0.66, 0.36, j(0.1), j(0.1), 0.0),
            ("p", [(0.74, 0.34), (j(0.88), 0.38), (0.74, 0.42)]),
            ("l", [(0.62, 0.4), (0.6, 0.6)], 0.1),
            ("p", [(0.24, 0.6), (j(0.14), j(0.48)), (0.3, 0.54)]),
        ]
    if kind == "giraffe":
        return [
            ("e", 0.4, 0.55, j(0.2), j(0.1), 0.0),
            ("l", [(0.55, 0.52), (j(0.7), j(0.18))], 0.08),
            ("e", 0.74, 0.17, j(0.08), 0.04, 0.3),
            *legs((0.25, 0.34, 0.47, 0.54), 0.6, 0.92, 0.045),
            ("l", [(0.21, 0.52), (0.14, 0.66)], 0.025),
        ]
    raise DatasetError(f"unknown procedural silhouette {kind!r}")


SHAPE_KINDS = ("cat", "rabbit", "bird", "fish", "dog", "turtle", "snail", "tree", "mushroom",
               "cactus", "duck", "giraffe")


def procedural_silhouette(kind: str, rng: np.random.Generator, size: int = 50) -> Target:
    """A simple animal or object silhouette drawn from ellipses, polygons and thick lines,
    jittered by rng, fitted with a margin; automatic start."""
    n = size * SUPERSAMPLE
    img = Image.new("L", (n, n), 0)
    draw = ImageDraw.Draw(img)
    for part in _shape_parts(kind, rng):
        if part[0] == "e":
            _, cx, cy, rx, ry, ang = part
            draw.polygon(_ellipse_poly(cx * n, cy * n, rx * n, ry * n, ang), fill=255)
        elif part[0] == "p":
            draw.polygon([(x * n, y * n) for x, y in part[1]], fill=255)
        else:
            pts = [(x * n, y * n) for x, y in part[1]]
            wid = part[2] * n
            draw.line(pts, fill=255, width=max(1, int(round(wid))), joint="curve")
            for x, y in (pts[0], pts[-1]):
                draw.ellipse((x - wid / 2, y - wid / 2, x + wid / 2, y + wid / 2), fill=255)
    mask = drop_specks(np.asarray(img) >= 128, 0.5)  # keep the main body only
    fitted, _ = fit_mask(mask, size)
    return Target(fitted, auto_start(fitted), kind)


def build_silhouettes(count: int | None, seed: int, size: int,
                      source_dir: str | os.PathLike | None = None, polarity: str = "auto",
                      **_: object) -> Iterator[Item]:
    made = 0

    def room() -> bool:
        return count is None or made < count

    if source_dir is not None:
        src = Path(source_dir)
        if not src.is_dir():
            raise DatasetError(f"silhouette directory {src} does not exist")
        for path in sorted(p for p in src.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES):
            if not room():
                return
            try:
                target = silhouette_from_image(path, size, polarity)
            except TargetError as err:
                warnings.warn(f"skipped {err}", DatasetWarning, stacklevel=2)
                continue
            made += 1
            yield target, f"file {path.name}"
    if not room():
        return
    from skimage.data import horse

    fitted, _ = fit_mask(~horse(), size)  # the horse is dark (False) on white
    made += 1
    yield Target(fitted, auto_start(fitted), "horse"), "skimage.data.horse"
    limit = count - made if count is not None else 2 * len(SHAPE_KINDS)
    yield from build_shapes(limit, seed, size)


def build_shapes(count: int | None, seed: int, size: int, **_: object) -> Iterator[Item]:
    """Procedural animal and object silhouettes alone (the kinds in turn)."""
    for j in range(300 if count is None else count):
        kind = SHAPE_KINDS[j % len(SHAPE_KINDS)]
        target = procedural_silhouette(kind, np.random.default_rng([seed, j]), size)
        yield target, f"procedural {kind} {j // len(SHAPE_KINDS)}"


# --- clip-art silhouettes (public domain) ------------------------------------------------

CLIPART_DIR = Path("/usr/share/openclipart/svg/animals")  # Debian package openclipart-svg
CLIPART_FILL = (0.08, 0.6)  # usable silhouettes fill this fraction of the canvas
CLIPART_MAX_BOX = 0.75  # ... and at most this fraction of their bounding box (no frames)
CLIPART_MAIN = 0.8  # ... and their largest part holds this fraction of the pixels


def rasterize_svg(svg: Path, png: Path, side: int = 200) -> None:
    """SVG -> PNG with a transparent background (rsvg-convert, Debian package librsvg2-bin)."""
    import shutil
    import subprocess

    exe = shutil.which("rsvg-convert")
    if exe is None:
        raise DatasetError("rsvg-convert not found (apt-get install librsvg2-bin)")
    try:
        subprocess.run([exe, "-w", str(side), "-h", str(side), "-a", "-o", str(png), str(svg)],
                       check=True, capture_output=True, timeout=60)
    except (subprocess.SubprocessError, OSError) as err:
        raise TargetError(f"{svg}: cannot rasterize ({err.__class__.__name__})") from None


def clipart_files(source: Path) -> list[Path]:
    """SVG and raster images under `source` (recursively), in a fixed order."""
    return sorted(p for p in source.rglob("*")
                  if p.is_file() and (p.suffix.lower() == ".svg" or
                                      p.suffix.lower() in IMAGE_SUFFIXES))


def clipart_reject(mask: np.ndarray) -> str | None:
    """Why a clip-art mask is no usable silhouette (None: usable)."""
    frac = float(mask.mean())
    if not CLIPART_FILL[0] <= frac <= CLIPART_FILL[1]:
        return f"fills {frac:.0%} of the canvas"
    rows, cols = np.nonzero(mask)
    box = (rows.max() - rows.min() + 1) * (cols.max() - cols.min() + 1)
    if mask.sum() > CLIPART_MAX_BOX * box:
        return f"fills {mask.sum() / box:.0%} of its bounding box (a frame or a disc)"
    counts = np.bincount(label(mask).ravel())[1:]
    if counts.max() < CLIPART_MAIN * counts.sum():
        return "in several large parts"
    return None


def build_clipart(count: int | None, seed: int, size: int,
                  source_dir: str | os.PathLike | None = None, **_: object) -> Iterator[Item]:
    """Silhouettes (the opaque pixels) of clip art, by default Openclipart's public-domain
    animal drawings; files spread evenly over the sorted list, unusable ones skipped
    (too small, a filled rectangle, one color)."""
    import tempfile

    src = Path(source_dir) if source_dir is not None else CLIPART_DIR
    if not src.is_dir():
        raise DatasetError(f"clip-art directory {src} does not exist "
                           "(apt-get install openclipart-svg librsvg2-bin)")
    files = clipart_files(src)
    order = np.random.default_rng(seed).permutation(len(files)) if seed else range(len(files))
    made = 0
    with tempfile.TemporaryDirectory() as tmp:
        for i in order:
            if count is not None and made >= count:
                return
            path = files[int(i)]
            try:
                png = path
                if path.suffix.lower() == ".svg":
                    png = Path(tmp) / f"{path.stem}.png"
                    rasterize_svg(path, png)
                target = silhouette_from_image(png, size, "alpha")
            except TargetError as err:
                warnings.warn(f"skipped {err}", DatasetWarning, stacklevel=2)
                continue
            why = clipart_reject(target.mask)
            if why:
                warnings.warn(f"skipped {path.name}: {why}", DatasetWarning, stacklevel=2)
                continue
            made += 1
            yield Target(target.mask, target.start, "clipart"), \
                f"openclipart {path.relative_to(src)}"


# --- registry and build ------------------------------------------------------------------

DATASETS: dict[str, DatasetSpec] = {
    "scribbles": DatasetSpec(
        "scribbles", "synthetic hand-drawn-looking strokes, start where the stroke began "
        "(training)", 300, build_scribbles),
    "glyphs": DatasetSpec(
        "glyphs", "font glyphs with one connected component (default DejaVu Sans Bold; "
        "--font PATH for any TTF/OTF), automatic start (testing)", None, build_glyphs),
    "silhouettes": DatasetSpec(
        "silhouettes", "images from --from DIR, scikit-image's horse and procedural animal "
        "and object silhouettes, automatic start unless a sidecar exists (testing)",
        None, build_silhouettes),
    "shapes": DatasetSpec(
        "shapes", "procedural animal and object silhouettes (those of `silhouettes` without "
        "the horse; use another --seed than a test set's), automatic start (training)",
        300, build_shapes),
    "varied": DatasetSpec(
        "varied", "synthetic strokes of width 1-6 px, thin script-like loops, filled blobs "
        "and 2-3 disjoint parts, start where the first stroke began (training)", 300,
        build_varied),
    "clipart": DatasetSpec(
        "clipart", "silhouettes of public-domain clip art (default: Openclipart animals from "
        "Debian's openclipart-svg, --from DIR for others), automatic start (testing)",
        None, build_clipart),
}


def build_dataset(name: str, out_dir: str | os.PathLike, count: int | None = None,
                  seed: int = 0, size: int = 50, font: str | os.PathLike | None = None,
                  source_dir: str | os.PathLike | None = None, mirror: bool = False,
                  polarity: str = "auto") -> list[Path]:
    """Build dataset `name` into out_dir; returns the PNG paths in index order.

    Existing `NAME_####.png` files with sidecars are kept as they are (resume). Source
    items that cannot be used are skipped with a DatasetWarning. With mirror=True every
    target also gets a mirrored copy `NAME_####_m.png`.
    """
    spec = DATASETS.get(name)
    if spec is None:
        raise DatasetError(f"unknown dataset {name!r}; choose from {', '.join(DATASETS)}")
    if count is None:
        count = spec.default_count
    if count is not None and count < 0:
        raise DatasetError("count must be >= 0")
    if not isinstance(size, int) or size < 8:
        raise DatasetError("size must be an integer >= 8")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    params = {"name": name, "seed": seed, "size": size, "mirror": mirror,
              "font": str(font) if font is not None else None,
              "source_dir": str(source_dir) if source_dir is not None else None}
    _check_previous(out / "index.json", params)
    _write_index(out, {**params, "complete": False, "files": []})
    files: list[Path] = []
    sources: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DatasetWarning)
        for i, (target, source) in enumerate(spec.builder(
                count=count, seed=seed, size=size, font=font, source_dir=source_dir,
                polarity=polarity)):
            stem = f"{name}_{i:04d}"
            named = Target(target.mask, target.start, stem)
            versions = [named, named.mirrored()] if mirror else [named]
            for t in versions:
                path = out / f"{t.name}.png"
                if not (path.is_file() and sidecar_path(path).is_file()):
                    save_target(t, path)
                files.append(path)
                sources.append(source + (" (mirrored)" if t is not named else ""))
    skipped = [str(w.message) for w in caught if issubclass(w.category, DatasetWarning)]
    for w in caught:  # hand the warnings on to whoever called us
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    _write_index(out, {
        **params, "source": spec.description, "count": len(files), "complete": True,
        "skipped": len(skipped), "skipped_reasons": skipped,
        "files": [p.name for p in files], "sources": sources,
    })
    return files


def _check_previous(index: Path, params: dict) -> None:
    if not index.is_file():
        return
    try:
        old = json.loads(index.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        raise DatasetError(f"{index} is not valid JSON; remove it or use another directory") \
            from None
    diff = [k for k, v in params.items() if old.get(k) != v]
    if diff:
        raise DatasetError(f"{index.parent} holds a build with other settings "
                           f"({', '.join(diff)}); use another directory")


def _write_index(out: Path, meta: dict) -> None:
    atomic_write(out / "index.json", json.dumps(meta, indent=1) + "\n")


# --- contact sheets ----------------------------------------------------------------------


def draw_start(draw: ImageDraw.ImageDraw, px: float, py: float, dx: float, dy: float,
               length: float, head: float, width: int, dot: int) -> None:
    """A start pose: a green dot at (px, py) and a red arrow of `length` along (dx, dy)."""
    ex, ey = px + dx * length, py + dy * length
    draw.line((px, py, ex, ey), fill=(220, 30, 30), width=width)
    ang = math.atan2(dy, dx)
    for side in (2.6, -2.6):
        draw.line((ex, ey, ex + head * length * math.cos(ang + side),
                   ey + head * length * math.sin(ang + side)), fill=(220, 30, 30), width=width)
    draw.ellipse((px - dot, py - dot, px + dot, py + dot), fill=(20, 170, 40))


def contact_sheet(targets: list[Target], path: str | os.PathLike, cols: int | None = None,
                  cell: int = 64, labels: bool = True) -> Path:
    """Draw targets in a grid (shape dark gray on white), each start as a red arrow from a
    green dot, names below; written atomically as a palette PNG."""
    if not targets:
        raise DatasetError("nothing to draw: no targets")
    n = len(targets)
    cols = cols or max(1, min(n, int(math.ceil(math.sqrt(n * 1.5)))))
    rows = int(math.ceil(n / cols))
    label_h = 12 if labels else 0
    pad = 4
    sheet = Image.new("RGB", (cols * (cell + pad) + pad, rows * (cell + pad + label_h) + pad),
                      (235, 235, 235))
    draw = ImageDraw.Draw(sheet)
    font = _label_font()
    for k, t in enumerate(targets):
        r, c = divmod(k, cols)
        x0, y0 = pad + c * (cell + pad), pad + r * (cell + pad + label_h)
        tile = np.where(t.mask, 60, 255).astype(np.uint8)
        img = Image.fromarray(tile, mode="L").resize((cell, cell), Image.Resampling.NEAREST)
        sheet.paste(img.convert("RGB"), (x0, y0))
        sx, sy, dx, dy = t.start
        px, py = x0 + sx * cell, y0 + sy * cell
        draw_start(draw, px, py, dx, dy, 0.28 * cell, head=0.35, width=2, dot=3)
        if labels:
            text = t.name if len(t.name) <= cell // 6 else t.name.split("_", 1)[-1]
            draw.text((x0, y0 + cell + 1), text, fill=(0, 0, 0), font=font)
    buf = io.BytesIO()
    sheet.quantize(colors=32, method=Image.Quantize.MEDIANCUT).save(buf, format="PNG",
                                                                    optimize=True)
    path = atomic_write(path, buf.getvalue())
    return path


def _label_font() -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.truetype(str(default_font().with_name("DejaVuSans.ttf")), 9)
    except (OSError, ImportError):  # labels only: any font will do
        return ImageFont.load_default()
