"""Pictures of the shipped 3D grammars for the docs: docs/img/3d/<name>.png, one per 3D
grammar in grammars/ (docs/3d.md shows them).

Each picture is the one `ngpmc sample grammars/<name>.lsys -o <name>.png --size 384` draws
(seed 0, the default view 45,20), kept as a PNG of at most 64 colours so the repository stays
small; tests/test_gallery3d.py fails when a 3D grammar has no picture or a picture no grammar.

Usage: python scripts/gallery3d.py                         # every 3D grammar, 384 pixels
       python scripts/gallery3d.py --only plant3d --size 96 --out /tmp/gallery
       python scripts/gallery3d.py --check                 # exit 1 naming missing pictures
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
GRAMMARS = REPO / "grammars"
OUT = REPO / "docs" / "img" / "3d"
SIZE, SEED, COLORS = 384, 0, 64

if __name__ == "__main__":  # run as a script: the checkout's packages, installed or not
    sys.path[:0] = [str(REPO), str(REPO / "runtime")]


def grammars_3d(folder: Path = GRAMMARS) -> list[Path]:
    """The .lsys files in `folder` whose grammar is 3D, by name."""
    from ngpm_compiler.language.compile import compile_grammar

    return [p for p in sorted(folder.glob("*.lsys")) if compile_grammar(p).program().dim == 3]


def picture(path: Path, size: int = SIZE, seed: int = SEED) -> bytes:
    """The PNG file of a forward sample of the grammar at `path`, palette-quantized."""
    from ngpm_runtime import mesh_from_primitives
    from ngpm_runtime.inference.smc import forward
    from PIL import Image

    from ngpm_compiler.language.compile import compile_grammar

    prims = forward(compile_grammar(path).program(), seed=seed).primitives
    rgb = mesh_from_primitives(prims).render(size=size)
    pic = Image.fromarray(rgb).quantize(colors=COLORS, dither=Image.Dither.NONE)
    buf = io.BytesIO()
    pic.save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def missing(out: Path = OUT, folder: Path = GRAMMARS) -> list[str]:
    """Names of the 3D grammars in `folder` without a picture in `out`."""
    return [p.stem for p in grammars_3d(folder) if not (out / f"{p.stem}.png").is_file()]


def main(argv: list[str] | None = None) -> int:
    from ngpm_runtime.files import atomic_write

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUT, help="folder (default docs/img/3d)")
    parser.add_argument("--size", type=int, default=SIZE, help=f"pixels (default {SIZE})")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="these grammars only")
    parser.add_argument(
        "--check",
        action="store_true",
        help="write nothing; exit 1 when a 3D grammar has no picture",
    )
    args = parser.parse_args(argv)
    if args.check:
        lacking = missing(args.out)
        if lacking:
            print(
                f"no picture in {args.out} for: {', '.join(lacking)}; "
                "run python scripts/gallery3d.py"
            )
        return 1 if lacking else 0
    paths = grammars_3d()
    if args.only:
        unknown = sorted(set(args.only) - {p.stem for p in paths})
        if unknown:
            parser.error(f"not a shipped 3D grammar: {', '.join(unknown)}")
        paths = [p for p in paths if p.stem in args.only]
    for path in paths:
        t0 = time.perf_counter()
        data = picture(path, args.size)
        atomic_write(args.out / f"{path.stem}.png", data)
        print(
            f"{args.out / path.stem}.png: {len(data) // 1024} KiB, {time.perf_counter() - t0:.1f} s"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
