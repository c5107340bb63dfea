"""The `glyphs` set: font glyphs with one connected component (testing), by default DejaVu
Sans Bold; automatic start."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from ngpm_runtime.image.morphology import label
from ngpm_runtime.image.targets import Target, auto_start, resize_mask
from PIL import Image, ImageDraw, ImageFont

from ngpm_compiler.datasets.common import SUPERSAMPLE, DatasetError, Item

MIN_GLYPH_FRACTION = 0.04  # a glyph must cover at least 4% of the image (100 px at 50 x 50)
GLYPH_RANGES = ((0x21, 0x7E), (0xC0, 0x17F), (0x391, 0x3C9), (0x410, 0x44F))


def default_font() -> Path:
    """DejaVu Sans Bold, shipped with matplotlib."""
    import matplotlib

    return Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans-Bold.ttf"


def font_codepoints(font_path: Path) -> list[int]:
    """Code points in GLYPH_RANGES that the font maps to a glyph, ascending."""
    from fontTools.ttLib import TTFont

    try:
        with TTFont(str(font_path), lazy=True) as face:  # closed: no ResourceWarning later
            cmap = face.getBestCmap() or {}
    except Exception as err:  # fontTools raises many kinds on a bad file
        raise DatasetError(f"cannot read font {font_path}: {err}") from None
    return [
        c
        for lo, hi in GLYPH_RANGES
        for c in range(lo, hi + 1)
        if c in cmap and cmap[c] not in (".notdef", "space")
    ]


def render_glyph(font: ImageFont.FreeTypeFont, char: str, size: int) -> np.ndarray:
    """Mask of one glyph at a fixed scale: the frame is the font's ascent + descent (plus 8%),
    the glyph sits on the baseline and is centered horizontally; glyphs wider than the frame
    are padded to a square, which shrinks them."""
    ascent, descent = font.getmetrics()
    side = int(round((ascent + descent) * 1.08))
    left, top, right, bottom = font.getbbox(char, anchor="ls")
    width = int(max(side, right - left + 4))
    img = Image.new("L", (width, side), 0)
    base_y = (side - (ascent + descent)) // 2 + ascent
    x = (width - (right - left)) / 2 - left
    ImageDraw.Draw(img).text((x, base_y), char, font=font, fill=255, anchor="ls")
    mask = np.asarray(img) >= 128
    h, w = mask.shape
    square = np.zeros((w, w), dtype=bool)
    square[(w - h) // 2 : (w - h) // 2 + h] = mask
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


def build_glyphs(
    count: int | None, seed: int, size: int, font: str | os.PathLike[str] | None = None, **_: object
) -> Iterator[Item]:
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
