"""The 3D target sets (docs/3d.md, "3D targets"): `blobs3d` (unions of spheres, boxes,
capsules and cones) and `extruded` (scribbles, varied strokes and glyphs pushed into slabs)
for training, and `revolved` (silhouettes turned about their vertical middle) held out.

Each target is made in the unit cube, the frame `load_volume_target` and
`load_volume_dataset` place it from into a grammar's box, and written as `NAME_0000.npz`
with a picture `NAME_0000.png` (its voxels, shaded). Nothing is downloaded; a seed gives the
same files.
"""

from __future__ import annotations

import io
import os
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from ngpm_runtime.errors import TargetError
from ngpm_runtime.files import atomic_write
from ngpm_runtime.image.render3d import render_mesh
from ngpm_runtime.image.targets import Target, auto_start
from ngpm_runtime.volume.load import UNIT_BOX, volume_from_lattice
from ngpm_runtime.volume.target import VolumeTarget
from ngpm_runtime.volume.voxelize import extrude, revolve
from PIL import Image, ImageDraw, ImageFont

from ngpm_compiler.datasets.clipart import clipart_files, clipart_reject, rasterize_svg
from ngpm_compiler.datasets.common import DatasetError, DatasetWarning
from ngpm_compiler.datasets.glyphs import default_font, font_codepoints, glyph_ok, render_glyph
from ngpm_compiler.datasets.scribbles import scribble
from ngpm_compiler.datasets.silhouettes import (
    SHAPE_KINDS,
    procedural_silhouette,
    silhouette_from_image,
)
from ngpm_compiler.datasets.varied import varied

Item3d = tuple[VolumeTarget, str]  # a 3D target (name not final yet) and where it came from
BLOB_KINDS = ("sphere", "box", "capsule", "cone")
EXTRUDE_DEPTH = (0.1, 0.5)  # extruded slabs are this deep, in 2D picture sides
PREVIEW_SIZE = 160


# --- blobs3d ------------------------------------------------------------------------------


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    out: np.ndarray = q * np.sign(np.diag(r))
    return out


Inside = Callable[[np.ndarray], np.ndarray]


def _primitive(kind: str, rng: np.random.Generator, centre: np.ndarray, size: float) -> Inside:
    """A test `points (N, 3) -> inside (N,)` for one primitive about `centre`."""
    axis = _rotation(rng)[0]
    if kind == "sphere":
        r = size
        return lambda p: np.sum((p - centre) ** 2, axis=1) <= r * r
    if kind == "box":
        rot = _rotation(rng)
        half = size * rng.uniform(0.4, 1.0, 3)
        return lambda p: np.all(np.abs((p - centre) @ rot) <= half, axis=1)
    if kind == "capsule":
        r = size * rng.uniform(0.3, 0.55)
        a, b = centre - axis * size, centre + axis * size

        def capsule(p: np.ndarray) -> np.ndarray:
            t = np.clip((p - a) @ (b - a) / float((b - a) @ (b - a)), 0.0, 1.0)
            d = p - (a + t[:, None] * (b - a))
            return np.sum(d * d, axis=1) <= r * r

        return capsule
    height, radius = 2.0 * size, size * rng.uniform(0.5, 0.9)
    base = centre - axis * size

    def cone(p: np.ndarray) -> np.ndarray:
        t = (p - base) @ axis
        radial = np.linalg.norm((p - base) - t[:, None] * axis, axis=1)
        return (t >= 0) & (t <= height) & (radial <= radius * (1.0 - t / height))

    return cone


def blob3d(rng: np.random.Generator, resolution: int = 32) -> VolumeTarget:
    """A union of 2 to 5 primitives, each centred near the one before, drawn at twice
    the resolution and fitted to the unit cube; automatic start."""
    n = 2 * resolution
    c = (np.arange(n) + 0.5) / n
    points = np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1).reshape(-1, 3)
    inside = np.zeros(len(points), dtype=bool)
    centre = np.array([0.5, 0.3, 0.5])
    size = 0.0
    for _ in range(int(rng.integers(2, 6))):
        step = rng.normal(size=3)
        step[1] = abs(step[1])  # parts pile up rather than hang below
        new_size = float(rng.uniform(0.08, 0.2))
        centre = centre + step / np.linalg.norm(step) * 0.7 * (size + new_size) * (size > 0)
        centre = np.clip(centre, 0.2, 0.8)
        size = new_size
        kind = BLOB_KINDS[int(rng.integers(len(BLOB_KINDS)))]
        inside |= _primitive(kind, rng, centre, size)(points)
    return volume_from_lattice(inside.reshape(n, n, n), UNIT_BOX, resolution, "blob3d")


def build_blobs3d(count: int, seed: int, resolution: int, **_: object) -> Iterator[Item3d]:
    for i in range(count):
        yield blob3d(np.random.default_rng([seed, 31, i]), resolution), f"blobs3d {i}"


# --- extruded -----------------------------------------------------------------------------


def extruded(target: Target, depth: float, resolution: int, name: str) -> VolumeTarget:
    """A 2D target pushed `depth` picture sides along z, fitted to the unit cube; it starts
    where the 2D target does, halfway through the slab."""
    size = target.mask.shape[0]
    cells = max(1, int(round(depth * size)))
    x, y = target.start[0] * size, (1.0 - target.start[1]) * size
    start = np.array([x, y, cells / 2.0])
    return volume_from_lattice(extrude(target.mask, cells), UNIT_BOX, resolution, name, start)


def _glyph_maker(size: int, font: str | os.PathLike[str] | None) -> Callable[..., Target]:
    """A function rng -> a random usable glyph of the font (default DejaVu Sans Bold)."""
    font_path = Path(font) if font is not None else default_font()
    if not font_path.is_file():
        raise DatasetError(f"font file {font_path} does not exist")
    codes = font_codepoints(font_path)
    face = ImageFont.truetype(str(font_path), size * 4)

    def glyph(rng: np.random.Generator) -> Target:
        for _ in range(200):
            code = codes[int(rng.integers(len(codes)))]
            mask = render_glyph(face, chr(code), size)
            if glyph_ok(mask) is None:
                return Target(mask, auto_start(mask), f"glyph U+{code:04X}")
        raise DatasetError(f"{font_path.name}: no usable glyph in 200 tries")

    return glyph


def build_extruded(
    count: int, seed: int, resolution: int, font: str | os.PathLike[str] | None = None, **_: object
) -> Iterator[Item3d]:
    """Scribbles, varied strokes and glyphs in turn, drawn at the grid's resolution (so
    strokes stay at least a voxel wide), each pushed into a slab of random depth."""
    size = max(16, resolution)
    glyph = _glyph_maker(size, font)
    for i in range(count):
        rng = np.random.default_rng([seed, 37, i])
        kind = ("scribble", "varied", "glyph")[i % 3]
        if kind == "scribble":
            target, what = scribble(rng, size), "scribble"
        elif kind == "varied":
            made, info = varied(rng, size)
            target, what = made, f"varied {info['kind']}"
        else:
            target = glyph(rng)
            what = target.name
        depth = float(rng.uniform(*EXTRUDE_DEPTH))
        yield extruded(target, depth, resolution, "extruded"), f"extruded {what} depth {depth:.2f}"


# --- revolved -----------------------------------------------------------------------------


def revolved(target: Target, resolution: int, name: str) -> VolumeTarget:
    """A 2D silhouette turned about its vertical middle, fitted to the unit cube;
    automatic start."""
    return volume_from_lattice(revolve(target.mask), UNIT_BOX, resolution, name)


def build_revolved(
    count: int | None,
    seed: int,
    resolution: int,
    source_dir: str | os.PathLike[str] | None = None,
    polarity: str = "auto",
    **_: object,
) -> Iterator[Item3d]:
    """The procedural silhouettes (the `shapes` set's kinds in turn), or the pictures and
    SVG drawings under `--from DIR` (Openclipart: /usr/share/openclipart/svg/animals),
    revolved; pictures the clipart set would refuse (too small, a frame, in several large
    parts) skipped with a warning."""
    size = max(32, 2 * resolution)
    if source_dir is None:
        for j in range(2 * len(SHAPE_KINDS) if count is None else count):
            kind = SHAPE_KINDS[j % len(SHAPE_KINDS)]
            flat = procedural_silhouette(kind, np.random.default_rng([seed, 41, j]), size)
            yield revolved(flat, resolution, "revolved"), f"revolved procedural {kind}"
        return
    yield from _revolved_files(Path(source_dir), count, seed, resolution, size, polarity)


def _revolved_files(
    src: Path, count: int | None, seed: int, resolution: int, size: int, polarity: str
) -> Iterator[Item3d]:
    import tempfile

    if not src.is_dir():
        raise DatasetError(f"silhouette directory {src} does not exist")
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
                    flat = silhouette_from_image(png, size, "alpha")
                else:
                    flat = silhouette_from_image(png, size, polarity)
                why = clipart_reject(flat.mask)  # as the clipart set: no frames, no specks
                if why:
                    warnings.warn(f"skipped {path.name}: {why}", DatasetWarning, stacklevel=2)
                    continue
                target = revolved(flat, resolution, "revolved")
            except TargetError as err:
                warnings.warn(f"skipped {err}", DatasetWarning, stacklevel=2)
                continue
            made += 1
            yield target, f"revolved {path.relative_to(src)}"


# --- writing ------------------------------------------------------------------------------


def mirrored3d(target: VolumeTarget) -> VolumeTarget:
    """The target mirrored in x about the grid's middle; name gets the suffix `_m`."""
    start = target.start.copy()
    start[0] = target.lo[0] + target.hi[0] - start[0]
    occ = target.occupancy[::-1].copy()
    return VolumeTarget(occ, target.lo, target.voxel, start, target.name + "_m")


def save_volume(target: VolumeTarget, path: Path) -> Path:
    """`path` (.npz) and a picture of its voxels beside it (.png), each atomically."""
    buf = io.BytesIO()
    Image.fromarray(render_mesh(target.mesh(), PREVIEW_SIZE)).save(buf, format="PNG")
    atomic_write(path.with_suffix(".png"), buf.getvalue())
    return target.to_npz(path)


def volume_sheet(
    targets: list[VolumeTarget],
    path: str | os.PathLike[str],
    cols: int | None = None,
    cell: int = 64,
) -> Path:
    """Pictures of 3D targets' voxels in a grid, names below; written atomically."""
    if not targets:
        raise DatasetError("nothing to draw: no targets")
    n = len(targets)
    cols = cols or max(1, min(n, int(np.ceil(np.sqrt(n * 1.5)))))
    rows = -(-n // cols)
    pad, label_h = 4, 12
    sheet = Image.new(
        "RGB", (cols * (cell + pad) + pad, rows * (cell + pad + label_h) + pad), "white"
    )
    draw = ImageDraw.Draw(sheet)
    for k, t in enumerate(targets):
        r, c = divmod(k, cols)
        x0, y0 = pad + c * (cell + pad), pad + r * (cell + pad + label_h)
        sheet.paste(Image.fromarray(render_mesh(t.mesh(), cell)), (x0, y0))
        text = t.name if len(t.name) <= cell // 6 else t.name.split("_", 1)[-1]
        draw.text((x0, y0 + cell + 1), text, fill=(0, 0, 0))
    buf = io.BytesIO()
    sheet.save(buf, format="PNG", optimize=True)
    return atomic_write(path, buf.getvalue())
