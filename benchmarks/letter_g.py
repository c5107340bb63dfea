"""The letter "G" check of issue #11: does guided N = 10 fill a "G" in every run?

The authors' 2016 sketch demo grows vines into a hand-drawn "G"; their guide at N = 10 fills
it in 5 of 5 runs. We do not have their drawing, so G targets stand in for it: a sketched G
(a brush stroke of about 4 px along an open circle with a bar, drawn here with Pillow) with
the automatic start and with the pen's start (where a hand would begin a G), the DejaVu Sans
Bold "G" (a filled glyph) and the URW Z003 "G" (a thin script glyph, when fonts-urw-base35
is installed). Each guide runs `--seeds` seeded SMC runs per target
(seeds 0..S-1); printed per run: similarity and coverage (the fraction of the target's pixels
the vine covers); a run "fills" the letter when coverage >= `--fill` (default 0.5). With
`-o PNG` a grid of every run's vine over its target is written (rows: guide x target).

Usage: python benchmarks/letter_g.py [--guide NAME=PATH ...] [--seeds 5] [-N 10] [-o g.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from ngpm_runtime import bundled
from ngpm_runtime.grow import grow
from ngpm_runtime.image.render import render_array
from ngpm_runtime.image.targets import Target, auto_start, resize_mask
from ngpm_runtime.inference.guide import Guide
from PIL import Image, ImageDraw, ImageFont

Z003 = Path("/usr/share/fonts/opentype/urw-base35/Z003-MediumItalic.otf")
SIZE = 50


def sketched_g(size: int = SIZE) -> np.ndarray:
    """A G as a sketch pad would record it: an open circle and a bar, a 4 px brush at 50 px."""
    big = 8 * size
    img = Image.new("L", (big, big), 0)
    d = ImageDraw.Draw(img)
    w = int(0.08 * big)
    box = (0.14 * big, 0.14 * big, 0.86 * big, 0.86 * big)
    d.arc(box, start=35, end=330, fill=255, width=w)  # open on the upper right
    d.line((0.52 * big, 0.52 * big, 0.86 * big, 0.52 * big), fill=255, width=w)
    d.line((0.84 * big, 0.5 * big, 0.84 * big, 0.72 * big), fill=255, width=w)
    return resize_mask(np.asarray(img) > 127, size)


def font_g(font: Path, size: int = SIZE) -> np.ndarray:
    """The font's "G", fitted into the square with a small margin."""
    big = 8 * size
    img = Image.new("L", (big, big), 0)
    face = ImageFont.truetype(str(font), int(0.8 * big))
    d = ImageDraw.Draw(img)
    x0, y0, x1, y1 = d.textbbox((0, 0), "G", font=face)
    d.text(((big - (x1 - x0)) / 2 - x0, (big - (y1 - y0)) / 2 - y0), "G", font=face, fill=255)
    return resize_mask(np.asarray(img) > 127, size)


def targets() -> dict[str, Target]:
    """Automatic starts, and the sketched G also with the pen's start: the upper end of
    the arc, heading along the stroke (up and left), as a sketch pad records it."""
    sketch = sketched_g()
    a = np.radians(330.0)  # Pillow's arc angles run clockwise from 3 o'clock (y down)
    pen = (0.5 + 0.36 * np.cos(a), 0.5 + 0.36 * np.sin(a), np.sin(a), -np.cos(a))
    out = {
        "sketched G": Target(sketch, auto_start(sketch), "sketched G"),
        "sketched G, pen start": Target(
            sketch, tuple(float(v) for v in pen), "sketched G, pen start"
        ),
    }
    fonts = {"DejaVu Sans Bold G": Path(ImageFont.truetype("DejaVuSans-Bold.ttf", 10).path)}
    if Z003.is_file():
        fonts["URW Z003 G"] = Z003
    for name, font in fonts.items():
        mask = font_g(font)
        out[name] = Target(mask, auto_start(mask), name)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--guide",
        action="append",
        default=[],
        help="NAME=PATH of a guide .onnx (repeatable; default: the bundled one)",
    )
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("-N", type=int, default=10, help="particles (default 10)")
    ap.add_argument("--fill", type=float, default=0.5, help="coverage that counts as filled")
    ap.add_argument("-o", "--out", help="PNG grid of every run")
    args = ap.parse_args()
    program = bundled.bundled_program()
    guides = dict(g.split("=", 1) for g in args.guide) or {"bundled": str(bundled.guide_path())}
    tiles: list[list[np.ndarray]] = []
    print(f"guided N = {args.N}, seeds 0..{args.seeds - 1}; per run: similarity / coverage")
    print("| guide | target | runs | filled | mean similarity | mean coverage |")
    print("|---|---|---|---|---|---|")
    for gname, path in guides.items():
        guide = Guide.load(path, program)
        for tname, target in targets().items():
            sims, covs, row = [], [], []
            for seed in range(args.seeds):
                res = grow(program, target, guide, args.N, seed=seed)
                covered = (res.image > 0) & target.mask
                sims.append(res.similarity)
                covs.append(covered.sum() / target.mask.sum())
                row.append(
                    render_array(res.primitives, program.viewport, 150, target_mask=target.mask)
                )
            tiles.append(row)
            filled = sum(c >= args.fill for c in covs)
            runs = " ".join(f"{s:.2f}/{c:.2f}" for s, c in zip(sims, covs, strict=True))
            print(
                f"| {gname} | {tname} | {runs} | {filled} of {args.seeds} | "
                f"{np.mean(sims):.3f} | {np.mean(covs):.3f} |"
            )
    if args.out:
        h, w, _ = tiles[0][0].shape
        grid = np.full((len(tiles) * (h + 4), args.seeds * (w + 4), 3), 255, dtype=np.uint8)
        for r, row in enumerate(tiles):
            for c, tile in enumerate(row):
                grid[r * (h + 4) : r * (h + 4) + h, c * (w + 4) : c * (w + 4) + w] = tile
        Image.fromarray(grid).save(args.out)
        print(f"grid: {args.out} (rows: guide x target, columns: seeds)")


if __name__ == "__main__":
    main()
