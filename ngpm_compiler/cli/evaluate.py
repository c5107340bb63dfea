"""`ngpmc eval`: reproduce the paper's experiments (shape matching, ablations, result grids,
circuits, chain) and write CSV files, PNG plots, README.md and report.md.

    ngpmc eval --quick -o OUT                      # CI-sized, everything made on the fly
    ngpmc eval -o work/results_big --work work/eval --traces work/vines/traces \\
        --guide-all work/vines/vines_guide.onnx    # the full run (docs/results/README.md)
    ngpmc eval -o OUT --stages heldout --heldout script=DIR,silhouettes=DIR \\
        --heldout-guides bundled=GUIDE.onnx        # held-out sets (scripts/expert_iteration.sh)
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

from ngpm_compiler.cli import argtypes
from ngpm_compiler.cli.guide import add_backend_arguments
from ngpm_compiler.experiments.config import STAGES, EvalConfig, eval_config, quick_config
from ngpm_compiler.experiments.pipeline import EvalError, run_eval


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "eval",
        help="run the paper's experiments and write results",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument(
        "-o",
        "--out",
        required=True,
        type=argtypes.path,
        help="results directory (CSV, PNG, Markdown)",
    )
    p.add_argument("--work", type=argtypes.path, help="scratch directory (default: OUT/work)")
    p.add_argument(
        "--quick",
        action="store_true",
        help="CI-sized run: tiny N, 2 targets, models from a few fresh traces",
    )
    _add_inputs(p)
    _add_runs(p)
    p.add_argument(
        "--stages",
        type=argtypes.choices((*STAGES, "heldout"), "stage"),
        default=STAGES,
        help=f"comma-separated subset of {','.join(STAGES)},heldout (default: all but heldout)",
    )
    p.add_argument("--seed", type=argtypes.seed, default=0, help="base seed (default 0)")
    p.add_argument(
        "--heldout",
        type=argtypes.pairs,
        help="stage heldout: NAME=DIR,... held-out target sets (default: none; "
        "the stage needs them)",
    )
    p.add_argument(
        "--heldout-guides",
        type=argtypes.pairs,
        default={},
        help="stage heldout: NAME=GUIDE.onnx,... guides to compare (default: the bundled guide)",
    )
    p.add_argument(
        "--heldout-targets",
        type=argtypes.count,
        default=16,
        help="stage heldout: targets per set, spread evenly (default 16)",
    )
    p.set_defaults(handler=cmd_eval)


def _add_inputs(p: argparse.ArgumentParser) -> None:
    """The grammars, traces, guide and target sets eval reads."""
    p.add_argument(
        "--grammar",
        type=argtypes.path,
        help="the vines grammar (.lsys or *_sampler.py; default: the sampler bundled "
        "with ngpm_runtime)",
    )
    p.add_argument(
        "--chain-grammar",
        type=argtypes.path,
        help="stage chain: the chain grammar (default: grammars/chain.lsys in the "
        "current folder, as in a checkout of the repository)",
    )
    p.add_argument(
        "--traces",
        type=argtypes.path,
        help="shape-matching traces directory (`ngpmc traces`; default: tiny ones made in --work)",
    )
    p.add_argument(
        "--guide-all",
        type=argtypes.path,
        help="use this .onnx as the all-features K=4 guide (default: train one)",
    )
    p.add_argument(
        "--glyphs", type=argtypes.path, help="glyph dataset directory (default: built in --work)"
    )
    p.add_argument(
        "--silhouettes", type=argtypes.path, help="silhouette dataset directory (default: built)"
    )


def _add_runs(p: argparse.ArgumentParser) -> None:
    """How many targets, particles, repeats and workers."""
    p.add_argument("--n-glyphs", type=argtypes.count, help="test glyphs (default 12)")
    p.add_argument("--n-silhouettes", type=argtypes.count, help="test silhouettes (default 6)")
    particle_counts = argtypes.integers(1, argtypes.MAX_PARTICLES)
    p.add_argument(
        "--ns", type=particle_counts, help="particle counts (default 1,2,5,10,20,50,100,200)"
    )
    p.add_argument(
        "--unguided-ns",
        type=particle_counts,
        help="extra particle counts for unguided SMC only (default 600)",
    )
    p.add_argument("--repeats", type=argtypes.count, help="SMC runs per target and N (default 3)")
    argtypes.add_workers(p, None, "2; quick: 1")
    add_backend_arguments(p)
    p.add_argument("--circuit-traces", type=argtypes.count, help="circuit traces (default 200)")
    p.add_argument(
        "--circuit-repeats", type=argtypes.count, help="circuit runs of each kind (default 5)"
    )


def config_from_args(args: argparse.Namespace) -> EvalConfig:
    out = str(args.out)
    work = str(args.work) if args.work else str(Path(out) / "work")
    if args.quick:
        cfg = quick_config(out, work, workers=args.workers or 1)
    else:
        cfg = eval_config(out, work)
    cfg.stages = tuple(args.stages)
    for key in (
        "grammar",
        "chain_grammar",
        "traces",
        "guide_all",
        "glyphs",
        "silhouettes",
        "n_glyphs",
        "n_silhouettes",
        "ns",
        "repeats",
        "workers",
        "circuit_traces",
        "circuit_repeats",
        "unguided_ns",
        "backend",
        "ray_address",
    ):
        v = getattr(args, key, None)
        key = "unguided_extra_ns" if key == "unguided_ns" else key
        if v is not None:
            cfg.set(key, v)
    cfg.set("seed", args.seed)
    if cfg.shape.ray_address and cfg.shape.backend != "ray":
        raise EvalError("--ray-address needs --backend ray")
    for key in ("traces", "guide_all", "glyphs", "silhouettes"):
        v = getattr(cfg.shape, key)
        if v is not None and not Path(v).exists():
            raise EvalError(f"--{key.replace('_', '-')} {v}: no such file or directory")
    needs = {
        "grammar": (cfg.shape.grammar, ("shape", "grids", "circuit")),
        "chain_grammar": (cfg.chain.chain_grammar, ("chain",)),
    }
    for key, (path, stages) in needs.items():
        if set(stages) & set(cfg.stages) and not Path(path).is_file():
            where = (
                " (grammars/chain.lsys of a clone of the ngpm repository; it is not "
                "installed with the package)"
                if key == "chain_grammar"
                else ""
            )
            raise EvalError(f"{path}: no such grammar; give --{key.replace('_', '-')} PATH" + where)
    return cfg


def cmd_eval(args: argparse.Namespace) -> int:
    stages = list(args.stages)
    if "heldout" in stages:
        run_heldout_stage(args)
        stages.remove("heldout")
        if not stages:
            return 0
        args.stages = tuple(stages)
    cfg = config_from_args(args)
    command = "ngpmc " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:] else ""
    run_eval(cfg, command=command, log=log_line)
    return 0


def log_line(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


def run_heldout_stage(args: argparse.Namespace) -> None:
    """`--stages heldout`: guides at N = 10 vs unguided N on the --heldout sets."""
    from ngpm_runtime import bundled

    from ngpm_compiler.evaluation.heldout import run_heldout

    if not args.heldout:
        raise EvalError("stage heldout needs --heldout NAME=DIR,...")
    sets, guides = args.heldout, dict(args.heldout_guides)
    if not guides:
        guides = {"bundled": str(bundled.guide_path())}
    for path in [*sets.values(), *guides.values()]:
        if not Path(path).exists():
            raise EvalError(f"{path}: no such file or directory")
    grammar = str(args.grammar or bundled.sampler_path())
    table = run_heldout(
        args.out,
        grammar,
        sets,
        guides,
        k=args.heldout_targets,
        repeats=args.repeats or 3,
        workers=args.workers or 2,
        unguided_ns=args.unguided_ns or (200, 600, 2000),
        seed=args.seed,
        log=log_line,
    )["table"]
    print(table)
