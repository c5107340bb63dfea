"""`ngpmc demo`: grow guided and unguided vines into the built-in targets, and the bundled
3D vine into 3D targets, side by side (ngpm_compiler.experiments.demo does the work)."""

from __future__ import annotations

import argparse

from ngpm_compiler.cli import argtypes
from ngpm_compiler.experiments import demo

DEFAULT_OUT = "ngpm_demo"


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "demo",
        help="grow guided and unguided vines into built-in targets (no training)",
        description="Grow the vines model into a few built-in targets with the bundled "
        "pretrained guide and without it (prior proposals), with the same number "
        "of particles, and write a side-by-side comparison.",
    )
    p.add_argument(
        "-o",
        "--out",
        type=argtypes.path,
        default=DEFAULT_OUT,
        help=f"output folder (default: {DEFAULT_OUT})",
    )
    p.add_argument(
        "-N",
        "--particles",
        type=argtypes.particles,
        default=10,
        help="particles per run, guided and unguided (default 10, at most "
        f"{argtypes.MAX_PARTICLES})",
    )
    p.add_argument("--seed", type=argtypes.seed, default=0, help="first seed (default 0)")
    p.add_argument(
        "--runs",
        type=argtypes.count,
        default=3,
        help="runs per target and kind, seeds seed, seed+1, ... (default 3)",
    )
    p.add_argument(
        "--no-3d",
        dest="with_3d",
        action="store_false",
        help="leave out the 3D rows (the bundled vines3d grown into 3D targets)",
    )
    p.set_defaults(handler=cmd_demo)


def cmd_demo(args: argparse.Namespace) -> int:
    from ngpm_runtime.bundled import DEMO_TARGETS, bundled_guide, bundled_guide3d, bundled_program

    from ngpm_compiler.experiments.demo3d import SOURCES, UNGUIDED_FACTOR

    program = bundled_program()
    guide = bundled_guide(program)
    guide3d = bundled_guide3d() if args.with_3d else None
    demo.prepare_out_dir(args.out)
    print(
        f"growing vines into {len(DEMO_TARGETS)} built-in targets, guided and unguided, "
        f"{args.particles} particles, {args.runs} runs each ...",
        flush=True,
    )
    if args.with_3d:
        print(
            f"then vines3d into {len(SOURCES)} 3D targets, guided with {args.particles} "
            f"particles and unguided with {UNGUIDED_FACTOR * args.particles} ...",
            flush=True,
        )
    rows, rows3d, files = demo.write_demo(
        args.out,
        args.particles,
        args.seed,
        args.runs,
        program,
        guide,
        guide3d,
        args.with_3d,
    )
    print(demo.summary_table(rows, args.particles, args.runs))
    if rows3d:
        print(demo.summary_table3d(rows3d, args.particles))
    print(f"wrote {files[-2]}, {files[-1]} and {len(files) - 2} renders in {files[-1].parent}")
    return 0
