"""`ngpmc learn`: from a grammar to a trained, tuned guide in one resumable command whose
stages fit a time budget (the work: experiments/learn.py)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ngpm_runtime.errors import NgpmError

from ngpm_compiler.cli import argtypes


def budget(text: str) -> float:
    """An argparse type: a duration such as 45m, 2h, 90s or 1h30m, in seconds."""
    from ngpm_compiler.experiments.learn_plan import parse_budget

    try:
        return parse_budget(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"not a duration such as 45m, 2h or 90s (at most 7 days): {text!r}"
        ) from None


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "learn",
        help="train a guide for a grammar in one resumable, budget-aware command",
        description="Diagnose the grammar, build training and validation targets, record "
        "unguided traces, train, run expert-iteration rounds with guided teachers, tune the "
        "best round, and write OUT/guide.onnx and OUT/report.md; the plan (traces, particles, "
        "rounds) fits --budget, and the run stops at it with the best guide so far. Run the "
        "same command again to resume (a finished stage is skipped). A 3D grammar (a "
        "'viewport:' box) learns on 3D targets (blobs3d and extruded).",
    )
    p.add_argument("grammar", help="the grammar's .lsys file")
    p.add_argument(
        "-o", "--out", required=True, type=argtypes.path, help="work folder (resumed if present)"
    )
    p.add_argument(
        "--likelihood",
        choices=("shape", "circuit"),
        default="shape",
        help="what the guide is for: shape (match target images, default) or circuit (the "
        "paper's circuit-like density: no targets, validated by equation 2's argument)",
    )
    p.add_argument(
        "--budget",
        type=budget,
        default=45 * 60.0,
        help="wall time for the whole run, e.g. 45m, 2h, 90s (default 45m; a resumed run "
        "counts the time spent before)",
    )
    p.add_argument(
        "--targets",
        type=argtypes.paths,
        default=(),
        help="training-target directories, comma-separated, or 'envelopes': filled "
        "silhouettes of the grammar's own samples, validated on other seeds' (default: build "
        "scribbles and varied strokes, and switch to envelopes when unguided SMC reaches "
        "those too poorly; a folder named envelopes: ./envelopes; a 3D grammar: 3D target "
        "sets, default blobs3d and extruded)",
    )
    p.add_argument(
        "--tune-teachers",
        action="store_true",
        help="tune each guided round's teacher (the best round's guide) on the validation "
        "targets first, as the final guide is tuned, and record its traces with those "
        "settings (a teacher under the default settings can be weaker than round 0's "
        "unguided one: docs/3d.md, 'Guided 3D growth'; default: off)",
    )
    argtypes.add_workers(p)
    p.add_argument("--seed", type=argtypes.seed, default=0, help="base seed (default 0)")
    p.set_defaults(handler=cmd_learn)


def cmd_learn(args: argparse.Namespace) -> int:
    from ngpm_compiler.experiments.learn import LearnConfig, learn

    if Path(args.grammar).suffix != ".lsys":
        raise NgpmError(f"{args.grammar}: ngpmc learn takes a grammar's .lsys file")
    if not Path(args.grammar).is_file():
        raise NgpmError(f"{args.grammar}: no such grammar file")
    if args.likelihood == "circuit" and args.targets:
        raise NgpmError(
            "the circuit likelihood has no targets: drop --targets (its runs start at the "
            "bottom middle of the viewport, heading up)"
        )
    if "envelopes" in args.targets and list(args.targets) != ["envelopes"]:
        raise NgpmError("--targets envelopes takes no other folders beside it")
    for d in args.targets:
        if d != "envelopes" and not Path(d).is_dir():
            raise NgpmError(f"--targets {d}: no such directory of targets")
    cfg = LearnConfig(
        grammar=args.grammar,
        out=args.out,
        budget=args.budget,
        likelihood=args.likelihood,
        targets=list(args.targets),
        workers=args.workers,
        seed=args.seed,
        progress=True,
        tune_teachers=args.tune_teachers,
    )
    res = learn(cfg, log=_log)
    spent = res["state"]["spent"]
    if res["stopped"]:
        print(
            f"ngpmc learn: the budget ran out during {res['stopped']}: {res['guide']} holds "
            f"the best finished guide; rerun with a larger --budget to go on "
            f"(report: {res['report']})",
            file=sys.stderr,
        )
    else:
        print(f"{res['guide']}: done in {spent / 60:.1f} min (report: {res['report']})")
    return 0


def _log(text: str) -> None:
    import time

    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)
