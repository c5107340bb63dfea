"""Contact sheets: targets drawn in a grid, each start as a red arrow from a green dot."""

from __future__ import annotations

import io
import math
import os
from pathlib import Path

import numpy as np
from ngpm_runtime.files import atomic_write
from ngpm_runtime.image.targets import Target
from PIL import Image, ImageDraw, ImageFont

from ngpm_compiler.datasets.common import DatasetError
from ngpm_compiler.datasets.glyphs import default_font


def draw_start(
    draw: ImageDraw.ImageDraw,
    px: float,
    py: float,
    dx: float,
    dy: float,
    length: float,
    head: float,
    width: int,
    dot: int,
) -> None:
    """A start pose: a green dot at (px, py) and a red arrow of `length` along (dx, dy)."""
    ex, ey = px + dx * length, py + dy * length
    draw.line((px, py, ex, ey), fill=(220, 30, 30), width=width)
    ang = math.atan2(dy, dx)
    for side in (2.6, -2.6):
        draw.line(
            (
                ex,
                ey,
                ex + head * length * math.cos(ang + side),
                ey + head * length * math.sin(ang + side),
            ),
            fill=(220, 30, 30),
            width=width,
        )
    draw.ellipse((px - dot, py - dot, px + dot, py + dot), fill=(20, 170, 40))


def contact_sheet(
    targets: list[Target],
    path: str | os.PathLike[str],
    cols: int | None = None,
    cell: int = 64,
    labels: bool = True,
) -> Path:
    """Draw targets in a grid (shape dark gray on white), each start as a red arrow from a
    green dot, names below; written atomically as a palette PNG."""
    if not targets:
        raise DatasetError("nothing to draw: no targets")
    n = len(targets)
    cols = cols or max(1, min(n, int(math.ceil(math.sqrt(n * 1.5)))))
    rows = int(math.ceil(n / cols))
    label_h = 12 if labels else 0
    pad = 4
    sheet = Image.new(
        "RGB", (cols * (cell + pad) + pad, rows * (cell + pad + label_h) + pad), (235, 235, 235)
    )
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
    sheet.quantize(colors=32, method=Image.Quantize.MEDIANCUT).save(
        buf, format="PNG", optimize=True
    )
    path = atomic_write(path, buf.getvalue())
    return path


def _label_font() -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    try:
        return ImageFont.truetype(str(default_font().with_name("DejaVuSans.ttf")), 9)
    except (OSError, ImportError):  # labels only: any font will do
        return ImageFont.load_default()
