"""`ngpmc targets build|list|show`: target datasets and contact sheets."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from ngpm_runtime.image.targets import POLARITIES, load_dataset, load_target

from ngpm_compiler.cli import argtypes
from ngpm_compiler.datasets.build import DATASETS, DatasetWarning, build_dataset, contact_sheet


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "targets", help="build, list and preview target image datasets",
        description="Build, list and preview target image datasets (see docs/datasets.md).")
    parser.set_defaults(handler=lambda _args: _help(parser))
    sub = parser.add_subparsers(dest="targets_command", metavar="ACTION")

    build = sub.add_parser("build", help="build a dataset into a directory")
    build.add_argument("name", choices=sorted(DATASETS), help="dataset to build")
    build.add_argument("-o", "--out", required=True, type=Path, help="output directory")
    build.add_argument("--count", type=int, default=None,
                       help="number of targets (default: the dataset's own)")
    build.add_argument("--seed", type=argtypes.seed, default=0, help="random seed (default 0)")
    build.add_argument("--size", type=int, default=50, help="working resolution (default 50)")
    build.add_argument("--font", type=Path, default=None,
                       help="TTF/OTF font for glyphs (default DejaVu Sans Bold)")
    build.add_argument("--from", dest="source_dir", type=Path, default=None,
                       help="directory of silhouette images")
    build.add_argument("--polarity", choices=POLARITIES, default="auto",
                       help="how to read --from images (default auto)")
    build.add_argument("--mirror", action="store_true", help="also write mirrored copies")
    build.set_defaults(handler=_build)

    lst = sub.add_parser("list", help="list the datasets that can be built")
    lst.set_defaults(handler=_list)

    show = sub.add_parser("show", help="draw a contact sheet of a dataset or images")
    show.add_argument("source", type=Path, help="dataset directory or one image")
    show.add_argument("-o", "--out", required=True, type=Path, help="output PNG")
    show.add_argument("--max", type=int, default=120, help="at most this many (default 120)")
    show.add_argument("--cols", type=int, default=None, help="columns (default: about square)")
    show.add_argument("--cell", type=int, default=64, help="cell size in pixels (default 64)")
    show.add_argument("--spread", action="store_true",
                      help="show --max targets spread evenly over the set, mirrors left out "
                           "(the ones `ngpmc eval --stages heldout` picks)")
    show.set_defaults(handler=_show)


def _help(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def _build(args: argparse.Namespace) -> int:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DatasetWarning)
        files = build_dataset(args.name, args.out, count=args.count, seed=args.seed,
                              size=args.size, font=args.font, source_dir=args.source_dir,
                              mirror=args.mirror, polarity=args.polarity)
    skipped = [w for w in caught if issubclass(w.category, DatasetWarning)]
    for w in skipped:
        print(f"ngpmc: warning: {w.message}", file=sys.stderr)
    extra = f", skipped {len(skipped)} unusable source file(s)" if skipped else ""
    print(f"{args.name}: {len(files)} targets in {args.out}{extra}")
    return 0


def _list(_args: argparse.Namespace) -> int:
    for spec in DATASETS.values():
        count = spec.default_count if spec.default_count is not None else "all"
        print(f"{spec.name:12s} default count {count!s:4s} {spec.description}")
    return 0


def _show(args: argparse.Namespace) -> int:
    if args.source.is_dir():
        targets = load_dataset(args.source)
    else:
        targets = [load_target(args.source)]
    if args.spread:
        from ngpm_compiler.experiments.shape import pick

        shown = pick([t for t in targets if not t.name.endswith("_m")], max(1, args.max))
    else:
        shown = targets[: max(1, args.max)]
    contact_sheet(shown, args.out, cols=args.cols, cell=args.cell)
    print(f"{args.out}: {len(shown)} of {len(targets)} targets")
    return 0
