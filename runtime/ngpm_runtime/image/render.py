"""Large color renders of finished results: RGB arrays, PNG (supersampled) and SVG.

Colors: branches from brown (thickest) to dark green (thinnest), leaves green, flowers
(disks) pink, polygons green. A target mask, when given, is drawn faintly behind, stretched
over the viewport (so pass the run's viewport with it).
"""

from __future__ import annotations

import base64
import io
import math
from collections.abc import Iterator
from pathlib import Path
from typing import cast

import numpy as np

from ngpm_runtime.errors import NgpmError
from ngpm_runtime.files import atomic_write
from ngpm_runtime.geometry.turtle import Prim
from ngpm_runtime.image.raster import Viewport, as_viewport, prim_mask, viewport_of

BACKGROUND = (255, 255, 255)
TARGET = (222, 226, 236)
BRANCH_THICK = (112, 74, 40)
BRANCH_THIN = (46, 92, 44)
LEAF = (74, 160, 64)
FLOWER = (236, 138, 178)
POLY = (96, 172, 84)


class RenderError(NgpmError):
    """A render cannot be written (unknown format, bad size)."""


def _widths(prims: list[Prim]) -> float:
    ws = [abs(p[5]) for p in prims if p[0] == "seg"]
    return max(ws) if ws else 1.0


def prim_color(prim: Prim, max_width: float) -> tuple[int, int, int]:
    """RGB color of a primitive (branches shade by width)."""
    kind = prim[0]
    if kind == "seg":
        t = min(1.0, abs(prim[5]) / max_width) if max_width > 0 else 1.0
        red, green, blue = (
            int(round(a + (b - a) * t)) for a, b in zip(BRANCH_THIN, BRANCH_THICK, strict=True)
        )
        return red, green, blue
    return {"leaf": LEAF, "disk": FLOWER, "poly": POLY}.get(kind, POLY)


def _image_size(viewport: Viewport, size: int) -> tuple[int, int]:
    xmin, xmax, ymin, ymax = viewport
    vw, vh = xmax - xmin, ymax - ymin
    if size < 1:
        raise RenderError(f"render size must be positive, got {size}")
    if vw >= vh:
        return max(1, int(round(size * vh / vw))), size
    return size, max(1, int(round(size * vw / vh)))


def _resize_nearest(mask: np.ndarray, h: int, w: int) -> np.ndarray:
    mask = np.asarray(mask, dtype=bool)
    rows = (np.arange(h) * mask.shape[0]) // h
    cols = (np.arange(w) * mask.shape[1]) // w
    out: np.ndarray = mask[rows[:, None], cols[None, :]]
    return out


def render_array(
    prims: list[Prim],
    viewport: Viewport | None = None,
    size: int = 256,
    target_mask: np.ndarray | None = None,
    supersample: int = 3,
) -> np.ndarray:
    """RGB uint8 image (h, w, 3) of the primitives; the longer side is `size` pixels."""
    return next(render_frames(prims, [len(prims)], viewport, size, target_mask, supersample))


def render_frames(
    prims: list[Prim],
    counts: list[int],
    viewport: Viewport | None = None,
    size: int = 256,
    target_mask: np.ndarray | None = None,
    supersample: int = 3,
) -> Iterator[np.ndarray]:
    """render_array(prims[:k]) for each k of the increasing `counts`, drawing each primitive
    once (later primitives paint over earlier ones, so the frames are the same)."""
    vp = viewport_of(prims) if viewport is None else as_viewport(viewport)
    h, w = _image_size(vp, int(size))
    s = max(1, int(supersample))
    big_h, big_w = h * s, w * s
    img = np.empty((big_h, big_w, 3), dtype=np.float32)
    img[:] = BACKGROUND
    if target_mask is not None:
        img[_resize_nearest(target_mask, big_h, big_w)] = TARGET
    wmax = _widths(prims)
    drawn = 0
    for k in counts:
        for p in prims[drawn:k]:
            y0, x0, m = prim_mask(p, vp, big_h, big_w)
            if m.any():
                ky, kx = m.shape
                img[y0 : y0 + ky, x0 : x0 + kx][m] = prim_color(p, wmax)
        drawn = max(drawn, k)
        yield _downsample(img, h, w, s)


def _downsample(img: np.ndarray, h: int, w: int, s: int) -> np.ndarray:
    """The mean of each s x s block as uint8 (sums of small integers: exact in float32, so
    the same as .mean(axis=(1, 3)), but several times faster)."""
    blocks = img.reshape(h, s, w, s, 3)
    rows = cast(np.ndarray, sum(blocks[:, i] for i in range(s)))  # s >= 1 blocks: an array
    small = cast(np.ndarray, sum(rows[:, :, j] for j in range(s))) / np.float32(s * s)
    out: np.ndarray = np.clip(np.round(small), 0, 255).astype(np.uint8)
    return out


def _png_bytes(rgb: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG")
    return buf.getvalue()


def _svg_text(prims: list[Prim], vp: Viewport, size: int, target_mask: np.ndarray | None) -> str:
    xmin, xmax, ymin, ymax = vp
    h, w = _image_size(vp, size)
    k = w / (xmax - xmin)
    out = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}">',
        f'<rect width="{w}" height="{h}" fill="rgb{BACKGROUND}"/>',
    ]
    if target_mask is not None:
        mask = np.asarray(target_mask, dtype=bool)
        rgb = np.empty(mask.shape + (3,), dtype=np.uint8)
        rgb[:] = BACKGROUND
        rgb[mask] = TARGET
        data = base64.b64encode(_png_bytes(rgb)).decode("ascii")
        out.append(
            f'<image width="{w}" height="{h}" preserveAspectRatio="none" '
            f'style="image-rendering:pixelated" href="data:image/png;base64,{data}"/>'
        )
    out.append(f'<g transform="translate({-xmin * k:.6g} {ymax * k:.6g}) scale({k:.6g} {-k:.6g})">')
    wmax = _widths(prims)
    for p in prims:
        col = "rgb({},{},{})".format(*prim_color(p, wmax))
        kind = p[0]
        if kind == "seg":
            _, x0, y0, x1, y1, width = p
            out.append(
                f'<line x1="{x0:.6g}" y1="{y0:.6g}" x2="{x1:.6g}" y2="{y1:.6g}" '
                f'stroke="{col}" stroke-width="{abs(width):.6g}" '
                'stroke-linecap="round"/>'
            )
        elif kind == "leaf":
            _, x, y, hd, length, width = p
            cx = x + length / 2 * math.cos(math.radians(hd))
            cy = y + length / 2 * math.sin(math.radians(hd))
            out.append(
                f'<ellipse cx="{cx:.6g}" cy="{cy:.6g}" rx="{abs(length) / 2:.6g}" '
                f'ry="{abs(width) / 2:.6g}" transform="rotate({hd:.6g} {cx:.6g} '
                f'{cy:.6g})" fill="{col}"/>'
            )
        elif kind == "disk":
            _, x, y, r = p
            out.append(f'<circle cx="{x:.6g}" cy="{y:.6g}" r="{abs(r):.6g}" fill="{col}"/>')
        elif kind == "poly":
            pts = " ".join(f"{vx:.6g},{vy:.6g}" for vx, vy in p[1])
            out.append(f'<polygon points="{pts}" fill="{col}" fill-rule="evenodd"/>')
    out.append("</g>")
    out.append("</svg>")
    return "\n".join(out) + "\n"


def save_render(
    prims: list[Prim],
    path: str | Path,
    viewport: Viewport | None = None,
    size: int = 512,
    target_mask: np.ndarray | None = None,
) -> Path:
    """Write a render as PNG or SVG (chosen by the suffix); returns the path."""
    path = Path(path)
    suffix = path.suffix.lower()
    vp = viewport_of(prims) if viewport is None else as_viewport(viewport)
    if suffix == ".png":
        data = _png_bytes(render_array(prims, vp, size, target_mask))
    elif suffix == ".svg":
        data = _svg_text(prims, vp, int(size), target_mask).encode("utf-8")
    else:
        raise RenderError(f"{path}: unknown render format {suffix or '(none)'!r}; use .png or .svg")
    try:
        atomic_write(path, data)
    except OSError as err:
        raise RenderError(f"{path}: cannot write render: {err.strerror or err}") from None
    return path


def save_steps_gif(
    prims: list[Prim],
    path: str | Path,
    viewport: Viewport,
    target_mask: np.ndarray | None = None,
    size: int = 256,
    max_frames: int = 60,
) -> Path:
    """An animated GIF of the growth: the primitives in drawing order, a few per frame."""
    from PIL import Image

    path = Path(path)
    n = len(prims)
    ks = sorted({int(k) for k in np.linspace(0, n, min(n, max_frames - 1) + 1).round()})
    frames = [Image.fromarray(rgb) for rgb in render_frames(prims, ks, viewport, size, target_mask)]
    # one palette, from the finished picture, for every frame (per-frame palettes cost
    # most of the time)
    palette = frames[-1].quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    frames = [f.quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    durations = [80] * len(frames)
    durations[-1] = 2000
    buf = io.BytesIO()
    frames[0].save(
        buf, format="GIF", save_all=True, append_images=frames[1:], duration=durations, loop=0
    )
    atomic_write(path, buf.getvalue())
    return path
