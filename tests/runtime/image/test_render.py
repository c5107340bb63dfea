"""Renders: colors in the right places, antialiasing, SVG structure, errors."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.image.render import (
    BACKGROUND,
    BRANCH_THICK,
    FLOWER,
    LEAF,
    TARGET,
    render_array,
    render_frames,
    save_render,
    save_steps_gif,
)
from PIL import Image

VP = (0.0, 10.0, 0.0, 10.0)
PRIMS = [
    ("seg", 1.0, 5.0, 9.0, 5.0, 1.0),
    ("disk", 8.0, 8.0, 1.0),
    ("leaf", 2.0, 2.0, 0.0, 3.0, 1.0),
    ("poly", ((6.0, 1.0), (9.0, 1.0), (9.0, 3.0))),
]


def _at(img: np.ndarray, x: float, y: float) -> tuple[int, ...]:
    h, w = img.shape[:2]
    return tuple(int(v) for v in img[int((10 - y) / 10 * h), int(x / 10 * w)])


def test_render_array_colors_and_antialias() -> None:
    mask = np.zeros((10, 10), dtype=bool)
    mask[0:2, 0:2] = True  # top-left world square [0, 2] x [8, 10]
    img = render_array(PRIMS, VP, 100, target_mask=mask)
    assert img.shape == (100, 100, 3) and img.dtype == np.uint8
    assert _at(img, 5.0, 5.0) == BRANCH_THICK
    assert _at(img, 8.0, 8.0) == FLOWER
    assert _at(img, 3.5, 2.0) == LEAF
    assert _at(img, 1.0, 9.0) == TARGET
    assert _at(img, 5.0, 9.0) == BACKGROUND
    # supersampling leaves intermediate shades along the disk's edge
    colors = {tuple(c) for c in img.reshape(-1, 3)}
    assert len(colors) > 8


def test_fit_viewport_and_aspect() -> None:
    img = render_array([("seg", 0.0, 0.0, 10.0, 0.0, 1.0)], None, 64)
    assert img.shape[1] == 64
    wide = render_array(PRIMS, (0.0, 20.0, 0.0, 10.0), 80)
    assert wide.shape == (40, 80, 3)


def test_save_png_and_svg(tmp_path) -> None:
    png = save_render(
        PRIMS, tmp_path / "a.png", VP, size=64, target_mask=np.ones((5, 5), dtype=bool)
    )
    with Image.open(png) as im:
        assert im.size == (64, 64) and im.mode == "RGB"
    svg = save_render(
        PRIMS, tmp_path / "a.svg", VP, size=64, target_mask=np.ones((5, 5), dtype=bool)
    )
    root = ET.parse(svg).getroot()
    tags = [el.tag.split("}")[1] for el in root.iter()]
    for tag in ("line", "circle", "ellipse", "polygon", "image"):
        assert tag in tags
    assert not list(tmp_path.glob(".*tmp"))


def test_bad_suffix_is_a_user_error(tmp_path) -> None:
    with pytest.raises(NgpmError):
        save_render(PRIMS, tmp_path / "a.jpg")


def test_growth_frames_equal_renders_of_each_prefix(tmp_path) -> None:
    prims = PRIMS + [("seg", 1.0, 1.0, 1.0, 9.0, 0.5), ("disk", 5.0, 5.0, 2.0)]
    counts = [0, 1, 3, 6]
    mask = np.zeros((5, 5), bool)
    mask[1:3, 1:4] = True
    for k, frame in zip(counts, render_frames(prims, counts, VP, 60, mask), strict=True):
        assert np.array_equal(frame, render_array(prims[:k], VP, 60, mask)), k
    gif = save_steps_gif(prims, tmp_path / "g.gif", VP, mask, size=60)
    with Image.open(gif) as img:
        assert img.n_frames == len(prims) + 1
