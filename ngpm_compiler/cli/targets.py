"""`ngpmc targets build|list|show`: target datasets and contact sheets."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from ngpm_runtime.image.targets import POLARITIES, load_dataset, load_target

from ngpm_compiler.cli import argtypes
from ngpm_compiler.cli.outpaths import check_output_file
from ngpm_compiler.datasets.build import DATASETS, build_dataset
from ngpm_compiler.datasets.common import DatasetError, DatasetWarning
from ngpm_compiler.datasets.sheets import contact_sheet


def _add_build(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """`ngpmc targets build`."""
    build = sub.add_parser("build", help="build a dataset into a directory")
    build.add_argument("name", choices=sorted(DATASETS), help="dataset to build")
    build.add_argument("-o", "--out", required=True, type=_path, help="output directory")
    build.add_argument(
        "--count",
        type=argtypes.count,
        default=None,
        help=f"number of targets (default: the dataset's own; at most {argtypes.MAX_COUNT})",
    )
    build.add_argument("--seed", type=argtypes.seed, default=0, help="random seed (default 0)")
    argtypes.add_target_size(build)
    build.add_argument(
        "--font",
        type=_path,
        default=None,
        help="TTF/OTF font for glyphs (default DejaVu Sans Bold)",
    )
    build.add_argument(
        "--from",
        dest="source_dir",
        type=_path,
        default=None,
        help="directory of silhouette images (default: the built-in silhouettes)",
    )
    build.add_argument(
        "--polarity",
        choices=POLARITIES,
        default="auto",
        help="how to read --from images (default auto)",
    )
    build.add_argument("--mirror", action="store_true", help="also write mirrored copies")
    build.add_argument(
        "--grammar",
        type=_path,
        default=None,
        help="the .lsys grammar whose forward samples `envelopes` are made from (default "
        "none: required by envelopes, refused by the other sets)",
    )
    build.add_argument(
        "--resolution",
        type=argtypes.integer(8, 128),
        default=32,
        help="voxels a side of the 3D sets (blobs3d, extruded, revolved; default 32)",
    )
    build.set_defaults(handler=_build)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "targets",
        help="build, list and preview target image datasets",
        description="Build, list and preview target image datasets (see docs/datasets.md).",
    )
    parser.set_defaults(handler=lambda _args: _help(parser))
    sub = parser.add_subparsers(dest="targets_command", metavar="ACTION")

    _add_build(sub)

    lst = sub.add_parser("list", help="list the datasets that can be built")
    lst.set_defaults(handler=_list)

    show = sub.add_parser("show", help="draw a contact sheet of a dataset or images")
    show.add_argument("source", type=_path, help="dataset directory or one image")
    show.add_argument(
        "-o", "--out", required=True, type=argtypes.output_file(".png"), help="output PNG"
    )
    show.add_argument(
        "--max",
        type=argtypes.integer(1, argtypes.MAX_SHEET),
        default=120,
        help=f"at most this many (default 120, at most {argtypes.MAX_SHEET})",
    )
    show.add_argument(
        "--cols",
        type=argtypes.integer(1, argtypes.MAX_COLUMNS),
        default=None,
        help=f"columns (default: about square; at most {argtypes.MAX_COLUMNS})",
    )
    show.add_argument(
        "--cell",
        type=argtypes.integer(8, argtypes.MAX_CELL),
        default=64,
        help=f"cell size in pixels (default 64, 8 to {argtypes.MAX_CELL})",
    )
    show.add_argument(
        "--size",
        type=argtypes.target_size,
        default=50,
        help="the working size to show them at, as grow reads them "
        f"(default 50, at most {argtypes.MAX_TARGET_SIZE})",
    )
    show.add_argument(
        "--spread",
        action="store_true",
        help="show --max targets spread evenly over the set, mirrors left out "
        "(the ones `ngpmc eval --stages heldout` picks)",
    )
    show.set_defaults(handler=_show)


def _path(text: str) -> Path:
    return Path(argtypes.path(text))


def _help(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def _build(args: argparse.Namespace) -> int:
    if args.grammar is not None and args.name != "envelopes":
        raise DatasetError(f"--grammar is for the envelopes set, not {args.name}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DatasetWarning)
        files = build_dataset(
            args.name,
            args.out,
            count=args.count,
            seed=args.seed,
            size=args.size,
            font=args.font,
            source_dir=args.source_dir,
            mirror=args.mirror,
            polarity=args.polarity,
            resolution=args.resolution,
            grammar=args.grammar,
        )
    skipped = [w for w in caught if issubclass(w.category, DatasetWarning)]
    for w in skipped:
        print(f"ngpmc: warning: {w.message}", file=sys.stderr)
    extra = f", skipped {len(skipped)} unusable source file(s)" if skipped else ""
    print(f"{args.name}: {len(files)} targets in {args.out}{extra}")
    return 0


def _is_3d(directory: Path) -> bool:
    """Whether a dataset directory holds a 3D set (.npz targets)."""
    index = directory / "index.json"
    return index.is_file() and '.npz"' in index.read_text(encoding="utf-8", errors="replace")


def _show3d(args: argparse.Namespace) -> int:
    """`targets show` of a 3D set: pictures of its voxels."""
    from ngpm_runtime.volume.load import load_volume_dataset

    from ngpm_compiler.datasets.sets3d import volume_sheet

    targets = load_volume_dataset(args.source)
    shown = targets[: args.max]
    volume_sheet(shown, args.out, cols=args.cols, cell=args.cell)
    print(f"{args.out}: {len(shown)} of {len(targets)} 3D targets")
    return 0


def _list(_args: argparse.Namespace) -> int:
    for spec in DATASETS.values():
        count = spec.default_count if spec.default_count is not None else "all"
        print(f"{spec.name:12s} default count {count!s:4s} {spec.description}")
    return 0


def _show(args: argparse.Namespace) -> int:
    check_output_file(args.out, "PNG file")
    if args.source.is_dir() and _is_3d(args.source):
        return _show3d(args)
    if args.source.is_dir():
        targets = load_dataset(args.source, size=args.size)
    else:
        targets = [load_target(args.source, size=args.size)]
    for t in targets:
        note = t.fit_note()
        if note:
            print(f"warning: {t.name}: {note}")
    if args.spread:
        from ngpm_compiler.evaluation.runs import pick

        shown = pick([t for t in targets if not t.name.endswith("_m")], args.max)
    else:
        shown = targets[: args.max]
    contact_sheet(shown, args.out, cols=args.cols, cell=args.cell)
    print(f"{args.out}: {len(shown)} of {len(targets)} targets")
    return 0
