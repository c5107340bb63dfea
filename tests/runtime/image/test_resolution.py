"""How much of a shape survives the working size, and the size to suggest."""

from __future__ import annotations

import numpy as np
from ngpm_runtime.image.resolution import shape_kept, suggest_size
from ngpm_runtime.image.targets import resize_mask
from PIL import Image, ImageDraw


def outline(side: int, width: int) -> np.ndarray:
    """A house outline (square body, roof) drawn with `width`-pixel lines."""
    img = Image.new("L", (side, side), 0)
    d = ImageDraw.Draw(img)
    s = side
    d.line(
        [
            (0.2 * s, 0.9 * s),
            (0.8 * s, 0.9 * s),
            (0.8 * s, 0.5 * s),
            (0.5 * s, 0.2 * s),
            (0.2 * s, 0.5 * s),
            (0.2 * s, 0.9 * s),
        ],
        fill=255,
        width=width,
    )
    return np.asarray(img) > 0


def test_a_filled_shape_is_kept_whole():
    square = np.zeros((400, 400), bool)
    square[100:300, 80:320] = True
    assert shape_kept(square, resize_mask(square, 50)) > 0.97


def test_thin_lines_vanish_at_50_and_a_larger_size_is_suggested():
    assert shape_kept(outline(800, 4), resize_mask(outline(800, 4), 50)) < 0.1
    square = outline(800, 8)
    assert shape_kept(square, resize_mask(square, 50)) < 0.4
    size = suggest_size(square, resize_mask, 50)
    assert size is not None and size > 50
    assert shape_kept(square, resize_mask(square, size)) >= 0.8
    # thick strokes survive at 50 x 50
    assert shape_kept(outline(800, 40), resize_mask(outline(800, 40), 50)) > 0.8


def test_no_size_to_suggest_for_hairlines_or_small_pictures():
    assert suggest_size(outline(800, 2), resize_mask, 50) is None
    assert suggest_size(outline(60, 2), resize_mask, 50) is None
    assert shape_kept(np.zeros((10, 10), bool), np.zeros((5, 5), bool)) == 1.0
