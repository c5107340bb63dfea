"""How much of a shape survives the working size, and the size to suggest."""

from __future__ import annotations

import numpy as np
from fixtures.pictures import house_mask
from ngpm_runtime.image.resolution import shape_kept, suggest_size
from ngpm_runtime.image.targets import resize_mask


def test_a_filled_shape_is_kept_whole():
    square = np.zeros((400, 400), bool)
    square[100:300, 80:320] = True
    assert shape_kept(square, resize_mask(square, 50)) > 0.97


def test_thin_lines_vanish_at_50_and_a_larger_size_is_suggested():
    assert shape_kept(house_mask(800, 4), resize_mask(house_mask(800, 4), 50)) < 0.1
    square = house_mask(800, 8)
    assert shape_kept(square, resize_mask(square, 50)) < 0.4
    size = suggest_size(square, resize_mask, 50)
    assert size is not None and size > 50
    assert shape_kept(square, resize_mask(square, size)) >= 0.8
    # thick strokes survive at 50 x 50
    assert shape_kept(house_mask(800, 40), resize_mask(house_mask(800, 40), 50)) > 0.8


def test_no_size_to_suggest_for_hairlines_or_small_pictures():
    assert suggest_size(house_mask(800, 2), resize_mask, 50) is None
    assert suggest_size(house_mask(60, 2), resize_mask, 50) is None
    assert shape_kept(np.zeros((10, 10), bool), np.zeros((5, 5), bool)) == 1.0
