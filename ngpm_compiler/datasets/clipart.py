"""The `clipart` set: silhouettes (the opaque pixels) of public-domain clip art, by default
Openclipart's animals from Debian's openclipart-svg (testing); automatic start."""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from ngpm_runtime.errors import TargetError
from ngpm_runtime.image.morphology import label
from ngpm_runtime.image.targets import IMAGE_SUFFIXES, Target

from ngpm_compiler.datasets.common import DatasetError, DatasetWarning, Item
from ngpm_compiler.datasets.silhouettes import silhouette_from_image

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
        subprocess.run(
            [exe, "-w", str(side), "-h", str(side), "-a", "-o", str(png), str(svg)],
            check=True,
            capture_output=True,
            timeout=60,
        )
    except (subprocess.SubprocessError, OSError) as err:
        raise TargetError(f"{svg}: cannot rasterize ({err.__class__.__name__})") from None


def clipart_files(source: Path) -> list[Path]:
    """SVG and raster images under `source` (recursively), in a fixed order."""
    return sorted(
        p
        for p in source.rglob("*")
        if p.is_file() and (p.suffix.lower() == ".svg" or p.suffix.lower() in IMAGE_SUFFIXES)
    )


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


def build_clipart(
    count: int | None,
    seed: int,
    size: int,
    source_dir: str | os.PathLike[str] | None = None,
    **_: object,
) -> Iterator[Item]:
    """Silhouettes (the opaque pixels) of clip art, by default Openclipart's public-domain
    animal drawings; files spread evenly over the sorted list, unusable ones skipped
    (too small, a filled rectangle, one color)."""
    import tempfile

    src = Path(source_dir) if source_dir is not None else CLIPART_DIR
    if not src.is_dir():
        raise DatasetError(
            f"clip-art directory {src} does not exist "
            "(apt-get install openclipart-svg librsvg2-bin)"
        )
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
            yield (
                Target(target.mask, target.start, "clipart"),
                f"openclipart {path.relative_to(src)}",
            )
