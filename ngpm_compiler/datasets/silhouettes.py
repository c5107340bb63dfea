"""The `silhouettes` and `shapes` sets: silhouettes from image files, scikit-image's horse and
procedural animal and object silhouettes; automatic start unless a sidecar gives one."""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.errors import TargetError
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
    sidecar_path,
)
from PIL import Image, ImageDraw

from ngpm_compiler.datasets.common import (
    SUPERSAMPLE,
    DatasetError,
    DatasetWarning,
    Item,
    ellipse_poly,
)

FIT_MARGIN = 0.1  # silhouettes are cropped and framed with 10% margin on each side
Part = tuple[Any, ...]  # a primitive of a procedural silhouette (see _shape_parts)


def fit_mask(
    mask: np.ndarray,
    size: int,
    margin: float = FIT_MARGIN,
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
    square[oy : oy + crop.shape[0], ox : ox + crop.shape[1]] = crop
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
    kept: np.ndarray = keep[labels]
    return kept


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


def _shape_parts(kind: str, rng: np.random.Generator) -> list[Part]:
    """Primitives of a procedural silhouette in unit coordinates (y down), jittered:
    ("e", cx, cy, rx, ry, angle) ellipses, ("p", [(x, y), ...]) polygons,
    ("l", [(x, y), ...], width) thick polylines.

    Long because it is a table of shape recipes, one branch per kind."""

    def j(v: float, amount: float = 0.06) -> float:
        return float(v * (1 + amount * rng.normal()))

    def legs(xs: tuple[float, ...], top: float, bottom: float, width: float) -> list[Part]:
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


SHAPE_KINDS = (
    "cat",
    "rabbit",
    "bird",
    "fish",
    "dog",
    "turtle",
    "snail",
    "tree",
    "mushroom",
    "cactus",
    "duck",
    "giraffe",
)


def procedural_silhouette(kind: str, rng: np.random.Generator, size: int = 50) -> Target:
    """A simple animal or object silhouette drawn from ellipses, polygons and thick lines,
    jittered by rng, fitted with a margin; automatic start."""
    n = size * SUPERSAMPLE
    img = Image.new("L", (n, n), 0)
    draw = ImageDraw.Draw(img)
    for part in _shape_parts(kind, rng):
        if part[0] == "e":
            _, cx, cy, rx, ry, ang = part
            draw.polygon(ellipse_poly(cx * n, cy * n, rx * n, ry * n, ang), fill=255)
        elif part[0] == "p":
            draw.polygon([(x * n, y * n) for x, y in part[1]], fill=255)
        else:
            pts = [(x * n, y * n) for x, y in part[1]]
            wid = part[2] * n
            draw.line(pts, fill=255, width=max(1, int(round(wid))), joint="curve")
            for x, y in (pts[0], pts[-1]):
                draw.ellipse((x - wid / 2, y - wid / 2, x + wid / 2, y + wid / 2), fill=255)
    mask = drop_specks(np.asarray(img) >= 128, 0.5)  # keep the main body only
    fitted = fit_mask(mask, size)[0]
    return Target(fitted, auto_start(fitted), kind)


def build_silhouettes(
    count: int | None,
    seed: int,
    size: int,
    source_dir: str | os.PathLike[str] | None = None,
    polarity: str = "auto",
    **_: object,
) -> Iterator[Item]:
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

    # the horse is dark (False) on white
    fitted = fit_mask(~horse(), size)[0]
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
