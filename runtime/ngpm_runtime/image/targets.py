"""Target images: a binary mask plus a start pose, loaded from any PNG/JPEG.

A target's start is `(x, y, dx, dy)`: a point normalized to [0, 1] with a top-left origin
(pixel column c covers x in [c/W, (c+1)/W)) and a unit direction in image axes (y down).
On disk a target is an image plus the original code's sidecar `<image stem>.txt`:
two lines, `x y` then `dx dy`. Images are padded to a square (background added equally on
both sides of the short axis, so the aspect is kept) and then resized to `size x size`
by area averaging; a pixel is foreground when at least half of it is covered.
"""

from __future__ import annotations

import io
import json
import math
import numbers
import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import BinaryIO

import numpy as np
from PIL import Image, ImageOps, PngImagePlugin, UnidentifiedImageError

from ngpm_runtime.errors import TargetError
from ngpm_runtime.files import atomic_write
from ngpm_runtime.image.morphology import (
    label,
    max_edt,
    neighbor_count,
    otsu_threshold,
    skeletonize,
)
from ngpm_runtime.image.resolution import KEEP_WARNING, MIN_SIDE, check_fit, fit_fix, fit_note

Start = tuple[float, float, float, float]  # (x, y, dx, dy), image axes, top-left origin

POLARITIES = ("auto", "dark", "light", "alpha")
DEFAULT_SIZE = 50
MIN_FOREGROUND = 0.004  # smallest foreground fraction after resizing (10 px at 50 x 50)
MAX_FOREGROUND = 0.95  # largest foreground fraction: above it there is no shape to match
POLARITY_KEY = "ngpm-polarity"  # PNG text chunk save_target writes (always "dark")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".gif", ".tif", ".tiff", ".webp")
IMAGE_FORMATS = ("PNG", "JPEG", "MPO", "GIF", "BMP", "TIFF", "WEBP")  # PIL's format names
FORMAT_NAMES = "PNG, JPEG, GIF, BMP, TIFF or WebP"
MAX_SIDE = 8192  # largest accepted image side, in pixels (so the padded square is bounded)
MAX_PIXELS = 2**25  # largest accepted width x height (33.5 million pixels, 8192 x 4096)
MAX_FRAMES = 32  # frames of an animation searched for one that holds a shape


class ImageFormatError(TargetError):
    """Not an image, or an image of a format that is not accepted."""


class ImageSizeError(TargetError):
    """An image with more pixels than the limits (found from its header, before decoding)."""


class ImageDecodeError(TargetError):
    """An image whose data cannot be decoded (truncated or damaged)."""


@dataclass(frozen=True, eq=False)
class Target:
    """A binary target mask with a start pose in normalized image coordinates."""

    mask: np.ndarray  # (H, W) bool, True = shape
    start: Start
    name: str = "target"
    kept: float = 1.0  # share of the picture's shape kept at this working size
    better_size: int | None = None  # a larger working size that keeps more, when kept is low

    def __post_init__(self) -> None:
        mask = np.asarray(self.mask)
        if mask.ndim != 2:
            raise TargetError(f"target {self.name}: mask must be 2-D, got shape {mask.shape}")
        object.__setattr__(self, "mask", mask.astype(bool, copy=False))
        object.__setattr__(self, "start", _check_start(self.start, f"target {self.name}"))

    @property
    def size(self) -> tuple[int, int]:
        """(height, width) of the mask."""
        return self.mask.shape[0], self.mask.shape[1]

    def start_pose(self, viewport: Sequence[float]) -> tuple[float, float, float]:
        """World pose (x, y, heading_degrees) of the start; world y points up."""
        xmin, xmax, ymin, ymax = (float(v) for v in viewport)
        x, y, dx, dy = self.start
        heading = math.degrees(math.atan2(-dy, dx))
        return xmin + x * (xmax - xmin), ymax - y * (ymax - ymin), heading

    def start_pixel(self) -> tuple[int, int]:
        """(row, col) of the pixel holding the start point."""
        h, w = self.size
        x, y = self.start[0], self.start[1]
        return min(int(y * h), h - 1), min(int(x * w), w - 1)

    def mirrored(self) -> Target:
        """Horizontally mirrored copy: x -> 1 - x, dx -> -dx; name gets suffix `_m`."""
        x, y, dx, dy = self.start
        return Target(
            self.mask[:, ::-1].copy(),
            (1.0 - x, y, -dx, dy),
            self.name + "_m",
            self.kept,
            self.better_size,
        )

    def fit_note(self) -> str | None:
        """A warning when the working size lost much of the picture's shape, else None."""
        if self.kept >= KEEP_WARNING:
            return None
        return fit_note(self.kept, self.better_size, self.mask.shape[0])


# --- sidecar -----------------------------------------------------------------------------


def sidecar_path(image_path: str | os.PathLike[str]) -> Path:
    """The sidecar file of an image: `<image stem>.txt` beside it."""
    return Path(image_path).with_suffix(".txt")


def read_sidecar(path: str | os.PathLike[str]) -> Start:
    """Read a 2-line sidecar (`x y`, `dx dy`); the direction is normalized to unit length."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise TargetError(f"cannot read sidecar {path}: {_reason(err)}") from None
    lines = [ln.replace(",", " ").split() for ln in text.splitlines() if ln.strip()]
    if len(lines) != 2 or any(len(ln) != 2 for ln in lines):
        raise TargetError(f"bad sidecar {path}: expected two lines 'x y' and 'dx dy'")
    try:
        values = [float(v) for ln in lines for v in ln]
    except ValueError:
        raise TargetError(f"bad sidecar {path}: not numbers: {text.strip()!r}") from None
    return _check_start(tuple(values), f"bad sidecar {path}:")


def write_sidecar(path: str | os.PathLike[str], start: Start) -> None:
    """Write a sidecar atomically."""
    x, y, dx, dy = _check_start(start, f"sidecar {path}:")
    atomic_write(path, f"{x:.6f} {y:.6f}\n{dx:.6f} {dy:.6f}\n".encode())


def _check_start(start: Sequence[float], where: str) -> Start:
    try:
        x, y, dx, dy = (float(v) for v in start)
    except (TypeError, ValueError):
        raise TargetError(f"{where} start must be four numbers (x, y, dx, dy)") from None
    if not all(math.isfinite(v) for v in (x, y, dx, dy)):
        raise TargetError(f"{where} start has a value that is not finite")
    eps = 1e-6
    if not (-eps <= x <= 1 + eps and -eps <= y <= 1 + eps):
        raise TargetError(f"{where} start point ({x:g}, {y:g}) is outside [0, 1]")
    norm = math.hypot(dx, dy)
    if norm < 1e-9:
        raise TargetError(f"{where} start direction ({dx:g}, {dy:g}) is zero")
    return min(max(x, 0.0), 1.0), min(max(y, 0.0), 1.0), dx / norm, dy / norm


# --- images -> masks ---------------------------------------------------------------------


def read_image(
    source: str | os.PathLike[str] | BinaryIO,
    name: str | None = None,
    *,
    max_side: int = MAX_SIDE,
    max_pixels: int = MAX_PIXELS,
) -> Image.Image:
    """Open and decode an image: a path, or a binary file object that `name` describes
    (default: "target image PATH"). The one loader of the command line, the server and
    `targets build --from`.

    The header's size is checked against `max_side` (each side, which bounds the square
    the image is padded to) and `max_pixels` before any pixel is decoded. Formats: PNG,
    JPEG, GIF, BMP, TIFF, WebP. An animation (or a multi-page TIFF) gives its first frame
    that holds a shape (see `_first_shape_frame`); a photo is turned as its EXIF
    orientation says. Every problem is a TargetError naming the image: ImageFormatError,
    ImageSizeError, ImageDecodeError, or a plain TargetError (missing file, no frame with
    a shape).
    """
    if name is None:
        name = f"target image {source}"
    img = _open_image(source, name)
    with img:
        _check_image(img, name, max_side, max_pixels)
        try:
            if getattr(img, "is_animated", False):
                return _first_shape_frame(img, name, max_side, max_pixels)
            img.load()
            info = dict(img.info)
            out = ImageOps.exif_transpose(img)  # photos: honor the camera's orientation
            out.info = info
            return out
        except TargetError:
            raise
        except Exception as err:  # a damaged file can make PIL raise nearly anything
            raise ImageDecodeError(f"cannot decode {name}: {_reason(err)}") from None


def _open_image(source: str | os.PathLike[str] | BinaryIO, name: str) -> Image.Image:
    """PIL's lazy open: the header only, no pixels."""
    try:
        return Image.open(source)
    except IsADirectoryError:
        raise TargetError(f"{source} is a folder, not an image") from None
    except FileNotFoundError:
        raise TargetError(f"{name} does not exist") from None
    except UnidentifiedImageError:
        raise ImageFormatError(f"cannot read {name}: not an image ({FORMAT_NAMES})") from None
    except Image.DecompressionBombError as err:
        raise ImageSizeError(f"cannot read {name}: {_reason(err)}") from None
    except (OSError, ValueError, SyntaxError, EOFError) as err:
        raise TargetError(f"cannot read {name}: {_reason(err)}") from None


def _check_image(img: Image.Image, name: str, max_side: int, max_pixels: int) -> None:
    """Refuse a format that is not accepted and a size over the limits (from the header)."""
    if img.format not in IMAGE_FORMATS:
        raise ImageFormatError(
            f"cannot read {name}: {img.format or 'unknown'} images are not "
            f"accepted ({FORMAT_NAMES})"
        )
    w, h = img.size
    if max(w, h) > max_side or w * h > max_pixels:
        raise ImageSizeError(
            f"cannot read {name}: the image is {w} x {h} px; the limit is "
            f"{max_side} px a side and {max_pixels:,} px in all"
        )


def _first_shape_frame(img: Image.Image, name: str, max_side: int, max_pixels: int) -> Image.Image:
    """The first frame of an animation (or page of a TIFF) that holds a shape (not one flat
    color), among the first MAX_FRAMES; its index is kept in `info["ngpm_frame"]`. An
    animation often starts blank (a growth GIF does). Each frame's size is checked before
    it is decoded (a TIFF's pages may differ)."""
    info = dict(img.info)
    count = 0
    for k in range(MAX_FRAMES):
        try:
            img.seek(k)
        except EOFError:
            break
        count = k + 1
        _check_image(img, name, max_side, max_pixels)
        img.load()
        frame = plain_mode(img.copy(), name)
        alpha = _alpha(frame)
        gray = _gray(frame)
        if (alpha is not None and int(alpha.max()) - int(alpha.min()) > 32) or int(
            gray.max()
        ) - int(gray.min()) > 16:
            frame.info = {**info, "ngpm_frame": k}
            return frame
    first = "first " if count == MAX_FRAMES else ""
    raise TargetError(
        f"{name}: none of the animation's {first}{count} frames holds a shape "
        "(every frame is one flat color)"
    )


def image_to_mask(img: Image.Image, polarity: str = "auto", name: str = "image") -> np.ndarray:
    """Foreground mask (H, W) bool of an image at its own resolution.

    polarity: "alpha" (opaque pixels), "dark" (dark shape on light), "light", or "auto":
    a PNG written by save_target says its polarity; otherwise alpha when the image has
    both transparent (alpha < 128) and opaque pixels; otherwise gray levels are split by
    Otsu's threshold and the class that covers most of the image border is the background
    (when the border is evenly split, the smaller class is the shape).
    """
    if polarity not in POLARITIES:
        raise TargetError(f"{name}: polarity must be one of {', '.join(POLARITIES)}")
    img = plain_mode(img, name)
    if min(img.size) < MIN_SIDE:
        raise TargetError(
            f"{name}: image is tiny ({img.width} x {img.height} px, "
            f"need at least {MIN_SIDE} x {MIN_SIDE})"
        )
    if polarity == "auto" and img.info.get(POLARITY_KEY) in ("dark", "light"):
        polarity = img.info[POLARITY_KEY]
    alpha = _alpha(img)
    if polarity == "auto" and alpha is not None and alpha.min() < 128 <= alpha.max():
        polarity = "alpha"
    if polarity == "alpha":
        if alpha is None:
            raise TargetError(f"{name}: polarity 'alpha' but the image has no alpha channel")
        if int(alpha.max()) - int(alpha.min()) <= 32:
            raise TargetError(f"{name}: alpha channel is flat, so it holds no shape")
        return alpha >= 128
    gray = _gray(img)
    if int(gray.max()) - int(gray.min()) <= 16:
        raise TargetError(f"{name}: image is one flat color, so it holds no shape")
    dark = gray <= otsu_threshold(gray)
    if polarity == "dark":
        return dark
    if polarity == "light":
        return ~dark
    border = np.concatenate([dark[0], dark[-1], dark[1:-1, 0], dark[1:-1, -1]])
    frac = float(border.mean())
    if frac < 0.4:
        return dark
    if frac > 0.6:
        return ~dark
    return dark if dark.mean() <= 0.5 else ~dark


# modes PIL cannot take gray levels (or alpha) from directly, and the mode to convert to
_PLAIN_VIA = {"LAB": "RGB", "La": "LA", "RGBa": "RGBA"}
_READABLE_MODES = (
    "1",
    "L",
    "LA",
    "P",
    "PA",
    "RGB",
    "RGBA",
    "RGBX",
    "CMYK",
    "YCbCr",
    "HSV",
    "I",
    "F",
)


def plain_mode(img: Image.Image, name: str = "image") -> Image.Image:
    """The image in a mode whose gray levels and alpha this module reads: LAB becomes RGB,
    the premultiplied La and RGBa become LA and RGBA, any other new mode RGBA; the modes
    it reads (L, RGB, CMYK, 16-bit, float, ...) are kept as they are."""
    if img.mode in _READABLE_MODES or img.mode.startswith("I;"):
        return img
    try:
        out = img.convert(_PLAIN_VIA.get(img.mode, "RGBA"))
    except ValueError:
        raise TargetError(f"{name}: images in PIL mode {img.mode} are not supported") from None
    out.info = dict(img.info)
    return out


def _gray(img: Image.Image) -> np.ndarray:
    """8-bit gray levels; 16-bit and float images are stretched from their min to max
    (NaN and infinity count as the lowest finite level)."""
    if not (img.mode in ("I", "F") or img.mode.startswith("I;")):
        return np.asarray(img.convert("L"), dtype=np.uint8)
    values = np.asarray(img)  # as stored (32-bit at most); float64 only a block at a time
    lo, hi = _finite_range(values)
    scale = 255.0 / (hi - lo) if hi > lo else 0.0
    out = np.empty(values.shape, dtype=np.uint8)
    for r in range(0, values.shape[0], 256):
        block = values[r : r + 256].astype(np.float64)
        block[~np.isfinite(block)] = lo
        out[r : r + 256] = np.round((block - lo) * scale)
    return out


def _finite_range(values: np.ndarray) -> tuple[float, float]:
    """(min, max) of the finite values; (0, 0) when there is none."""
    if values.dtype.kind != "f":
        return float(values.min()), float(values.max())
    finite = np.isfinite(values)
    if not finite.any():
        return 0.0, 0.0
    return (
        float(np.min(values, where=finite, initial=np.inf)),
        float(np.max(values, where=finite, initial=-np.inf)),
    )


def _alpha(img: Image.Image) -> np.ndarray | None:
    if img.mode == "P" and "transparency" in img.info:
        img = img.convert("RGBA")
    if img.mode in ("RGBA", "LA", "PA"):
        return np.asarray(img.getchannel("A"), dtype=np.uint8)
    return None


def pad_to_square(mask: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Pad with background to a square; returns (square, row offset, column offset)."""
    h, w = mask.shape
    side = max(h, w)
    oy, ox = (side - h) // 2, (side - w) // 2
    out = np.zeros((side, side), dtype=bool)
    out[oy : oy + h, ox : ox + w] = mask
    return out, oy, ox


def resize_mask(mask: np.ndarray, size: int) -> np.ndarray:
    """Resize a square mask to size x size: area average (box filter), foreground >= 1/2."""
    if mask.shape == (size, size):
        return mask.astype(bool, copy=True)
    levels = np.asarray(mask, dtype=bool).view(np.uint8) * np.uint8(255)  # one copy, not two
    img = Image.fromarray(levels)
    small = np.asarray(img.resize((size, size), Image.Resampling.BOX), dtype=np.uint8)
    return small >= 128


def mask_from_image(
    img: Image.Image,
    size: int | None = DEFAULT_SIZE,
    polarity: str = "auto",
    name: str = "image",
    start: Start | None = None,
) -> tuple[np.ndarray, Start | None]:
    """Mask at the working resolution and the start mapped through the square padding."""
    square, start, _kept, _better = _reduce(img, size, polarity, name, start)
    return square, start


def target_from_image(
    img: Image.Image,
    size: int | None = DEFAULT_SIZE,
    polarity: str = "auto",
    name: str = "image",
    start: Start | None = None,
) -> Target:
    """The Target of a picture at the working size: its start mapped through the square
    padding (found by `auto_start` when None) and how much of its shape the size keeps."""
    square, start, kept, better = _reduce(img, size, polarity, name, start)
    return Target(square, auto_start(square) if start is None else start, name, kept, better)


def _reduce(
    img: Image.Image, size: int | None, polarity: str, name: str, start: Start | None
) -> tuple[np.ndarray, Start | None, float, int | None]:
    """(mask at the working size, mapped start, share of the shape kept, a better size)."""
    mask = image_to_mask(img, polarity, name)
    h, w = mask.shape
    full, oy, ox = pad_to_square(mask)
    side = full.shape[0]
    square, kept, better = full, 1.0, None
    if size is not None:
        if isinstance(size, bool) or not isinstance(size, numbers.Integral) or size < MIN_SIDE:
            raise TargetError(f"{name}: working size must be an integer >= {MIN_SIDE}")
        square = resize_mask(full, int(size))
        kept, better = check_fit(full, square, resize_mask)
        if not square.any() and full.any():
            raise TargetError(f"{name}: no shape left at {size} x {size} px; " + fit_fix(better))
    check_mask(square, name)
    if start is not None:
        x, y, dx, dy = start
        start = ((x * w + ox) / side, (y * h + oy) / side, dx, dy)
    return square, start, kept, better


def check_mask(mask: np.ndarray, name: str) -> None:
    """Reject masks with (almost) no foreground or no background."""
    frac = float(mask.mean()) if mask.size else 0.0
    count = int(mask.sum())
    if count == 0:
        raise TargetError(
            f"{name}: no shape at {mask.shape[1]} x {mask.shape[0]} px "
            "(empty image, or strokes too thin for this size)"
        )
    if frac < MIN_FOREGROUND or count < 4:
        raise TargetError(
            f"{name}: shape is too small ({count} px of {mask.shape[1]} x {mask.shape[0]})"
        )
    if frac > MAX_FOREGROUND:
        raise TargetError(
            f"{name}: image is almost all foreground ({frac:.0%}); try another polarity"
        )


# --- loading and saving ------------------------------------------------------------------


def load_target(
    path: str | os.PathLike[str], size: int | None = DEFAULT_SIZE, polarity: str = "auto"
) -> Target:
    """Load an image as a Target at size x size (None: keep the padded square's size).

    The start comes from the sidecar `<stem>.txt` when there is one, else from
    `auto_start` on the mask.
    """
    path = Path(path)
    img = read_image(path)
    side = sidecar_path(path)
    start = read_sidecar(side) if side.is_file() else None
    target = target_from_image(img, size, polarity, str(path), start)
    return replace(target, name=path.stem)


def save_target(target: Target, path: str | os.PathLike[str]) -> Path:
    """Write the mask as a black-on-white PNG plus its sidecar, each atomically."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        path = path.with_suffix(".png")
    img = Image.fromarray(np.where(target.mask, 0, 255).astype(np.uint8), mode="L")
    info = PngImagePlugin.PngInfo()
    info.add_text(POLARITY_KEY, "dark")
    buf = io.BytesIO()
    img.save(buf, format="PNG", pnginfo=info, optimize=True)
    atomic_write(path, buf.getvalue())
    write_sidecar(sidecar_path(path), target.start)
    return path


def load_dataset(
    directory: str | os.PathLike[str], size: int | None = None, polarity: str = "auto"
) -> list[Target]:
    """Load every target of a dataset directory, in the order of its index.json.

    Without index.json, the images with a sidecar are loaded in name order; when no image
    has one, every image is, each with its start from `auto_start` (as `load_target` gives
    it). size=None keeps each image's own (square) size.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise TargetError(f"dataset directory {directory} does not exist")
    index = directory / "index.json"
    files: list[Path]
    if index.is_file():
        try:
            meta = json.loads(index.read_text(encoding="utf-8"))
            files = [directory / str(f) for f in meta["files"]]
        except (OSError, ValueError, KeyError, TypeError):
            raise TargetError(f"bad dataset index {index}: expected JSON with 'files'") from None
        if meta.get("complete") is False:
            raise TargetError(
                f"dataset {directory} is incomplete (interrupted build); "
                "run the same build command again"
            )
    else:
        images = sorted(
            p for p in directory.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()
        )
        files = [p for p in images if sidecar_path(p).is_file()] or images
    if not files:
        raise TargetError(
            f"dataset directory {directory} holds no targets (no index.json "
            f"and no images: {', '.join(sorted(IMAGE_SUFFIXES))})"
        )
    return [load_target(f, size=size, polarity=polarity) for f in files]


# --- automatic start annotation ----------------------------------------------------------


def auto_start(mask: np.ndarray) -> Start:
    """A deterministic start for a mask without annotation.

    Take the largest connected component's skeleton, prune its spurs (remove end pixels
    as many times as the shape's half thickness) and pick its lowest end pixel, so growth
    starts at the end of a stroke rather than in its middle (the lowest pixel of all when
    the skeleton has no end: a closed loop, a single pixel; ties: nearest the component's
    center column, then leftmost). From there the skeleton leaves in one or more branches
    (one from an end); the direction is the mean offset of each branch's pixels within
    `reach` steps (15% of the larger side, at least 3), and the most upward branch wins
    (ties: the one going right). Straight up when the skeleton is a single pixel. The point
    then moves backwards along the direction to the last pixel inside the shape, so growth
    starts at the shape's edge: a vertical bar starts at its bottom heading up.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        raise TargetError("cannot annotate an empty mask")
    h, w = mask.shape
    labels = label(mask)
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    comp = labels == int(np.argmax(counts))
    skel = skeletonize(comp)
    if not skel.any():
        skel = comp.copy()
    half = int(math.ceil(max_edt(comp)))
    skel = _prune(skel, half)
    ends = skel & (neighbor_count(skel) == 1)
    rows, cols = np.nonzero(ends if ends.any() else skel)
    center = float(np.nonzero(comp)[1].mean())
    low = int(rows.max())
    cand = cols[rows == low]
    c0 = int(cand[np.lexsort((cand, np.abs(cand - center)))[0]])
    r0 = low
    reach = max(3, int(round(0.15 * max(h, w))))
    dx, dy = _branch_direction(skel, r0, c0, reach)
    # walk back to the shape's edge (half-pixel steps, staying inside the component)
    py, px = r0 + 0.5, c0 + 0.5
    for _ in range(4 * max(h, w)):
        ny, nx = py - 0.5 * dy, px - 0.5 * dx
        ri, ci = int(math.floor(ny)), int(math.floor(nx))
        if not (0 <= ri < h and 0 <= ci < w and comp[ri, ci]):
            break
        py, px = ny, nx
    return px / w, py / h, dx, dy


_RING = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def _prune(skel: np.ndarray, times: int) -> np.ndarray:
    """Remove end pixels (at most one 8-neighbor) `times` times; never empties it."""
    for _ in range(times):
        nb = neighbor_count(skel)
        ends = skel & (nb <= 1)
        if not ends.any() or ends.sum() == skel.sum():
            break
        skel = skel & ~ends
    return skel


def _branch_direction(skel: np.ndarray, r0: int, c0: int, reach: int) -> tuple[float, float]:
    """Unit (dx, dy) along the most upward skeleton branch leaving (r0, c0)."""
    h, w = skel.shape
    first = [
        (r0 + dr, c0 + dc)
        for dr, dc in _RING
        if 0 <= r0 + dr < h and 0 <= c0 + dc < w and skel[r0 + dr, c0 + dc]
    ]
    if not first:
        return 0.0, -1.0
    # neighbors that touch each other start the same branch
    group = {q: i for i, q in enumerate(first)}
    for a in first:
        for b in first:
            if max(abs(a[0] - b[0]), abs(a[1] - b[1])) == 1:
                ga, gb = group[a], group[b]
                for q, g in group.items():
                    if g == gb:
                        group[q] = ga
    owner = dict(group)
    owner[(r0, c0)] = -1
    frontier = list(first)
    for _ in range(reach - 1):
        nxt = []
        for r, c in frontier:
            for dr, dc in _RING:
                q = (r + dr, c + dc)
                if 0 <= q[0] < h and 0 <= q[1] < w and q not in owner and skel[q]:
                    owner[q] = owner[(r, c)]
                    nxt.append(q)
        frontier = nxt
    best: tuple[float, float, float, float] | None = None
    for g in sorted(set(group.values())):
        pts = [q for q, o in owner.items() if o == g]
        vy = float(np.mean([q[0] for q in pts])) - r0
        vx = float(np.mean([q[1] for q in pts])) - c0
        norm = math.hypot(vx, vy)
        if norm < 1e-9:
            continue
        score = (round(-vy / norm, 6), round(vx / norm, 6))
        if best is None or score > best[:2]:
            best = (score[0], score[1], vx / norm, vy / norm)
    if best is None:
        return 0.0, -1.0
    return best[2], best[3]


# --- helpers -----------------------------------------------------------------------------


def _reason(err: BaseException) -> str:
    text = str(err).splitlines()[0] if str(err) else type(err).__name__
    return text[:160]
