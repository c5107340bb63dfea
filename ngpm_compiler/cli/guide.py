"""`ngpmc traces`, `train`, `iterate`, `export` and `tune`: learned guides, from traces to
tuned ONNX files (`grow`, which uses them: grow.py)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.image.features import FEATURE_SETS

from ngpm_compiler.cli import argtypes
from ngpm_compiler.cli.grammar import GRAMMAR_HELP
from ngpm_compiler.experiments.learn_plan import TUNE_CHOICES


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    _register_traces(subparsers)
    _register_train(subparsers)
    _register_iterate(subparsers)
    p = subparsers.add_parser("export", help="export a trained guide to one ONNX file")
    p.add_argument("model", help="model file written by `ngpmc train`")
    p.add_argument(
        "-o",
        "--out",
        required=True,
        type=argtypes.output_file(".onnx"),
        help="ONNX file to write (.onnx)",
    )
    p.set_defaults(handler=cmd_export)
    _register_tune(subparsers)


def _register_traces(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "traces", help="record training traces with SMC (unguided, or guided by --guide)"
    )
    p.add_argument("grammar", help=GRAMMAR_HELP)
    p.add_argument(
        "--targets",
        type=argtypes.path,
        help="dataset directory of target images (default none: the shape likelihood "
        "needs it, the circuit likelihood takes none)",
    )
    add_likelihood_argument(p)
    p.add_argument(
        "-n",
        type=argtypes.count,
        default=1000,
        help=f"traces to keep (default 1000, at most {argtypes.MAX_COUNT})",
    )
    p.add_argument(
        "--particles",
        type=argtypes.particles,
        default=600,
        help=f"SMC particles (default 600, at most {argtypes.MAX_PARTICLES})",
    )
    p.add_argument(
        "-o",
        "--out",
        required=True,
        type=argtypes.path,
        help="traces directory (resumed if present)",
    )
    argtypes.add_workers(p)
    p.add_argument("--seed", type=argtypes.seed, default=0, help="base seed (default 0)")
    p.add_argument(
        "--mirror", action="store_true", help="add mirrored copies of targets that have none"
    )
    argtypes.add_target_size(p)
    p.add_argument(
        "--shard-size", type=argtypes.count, default=50, help="jobs per shard (default 50)"
    )
    argtypes.add_max_modules(p)
    add_backend_arguments(p)
    p.add_argument(
        "--guide",
        type=argtypes.path,
        help="guide .onnx that proposes in SMC (expert iteration; default: "
        "unguided, the prior proposes)",
    )
    add_min_primitives(p)
    p.add_argument(
        "--sigma",
        type=argtypes.positive_number(1.0),
        help="a 3D grammar's voxel likelihood sigma (default 0.02, the paper's; a softer "
        "one, e.g. 0.05, keeps more particles alive: a stronger teacher at equal particles)",
    )
    p.add_argument(
        "--own-samples",
        action="store_true",
        help="ground-truth traces, no SMC: each job draws a forward sample and records its "
        "own choices into the envelope of its drawing (for targets that are envelopes of "
        "the grammar's samples, `ngpmc targets build envelopes`; no --targets)",
    )
    p.set_defaults(handler=cmd_traces)


def add_min_primitives(p: argparse.ArgumentParser) -> None:
    """--min-primitives (traces and iterate): by default every trace is kept."""
    p.add_argument(
        "--min-primitives",
        type=argtypes.integer(1, 10**6),
        default=1,
        metavar="N",
        help="drop a job whose best particle drew fewer than N primitives (default 1: "
        "short traces are kept as data, as `ngpmc learn` keeps them; the paper's code "
        "used 10)",
    )


def _register_train(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("train", help="train guide networks on recorded traces")
    p.add_argument(
        "traces",
        type=argtypes.paths,
        help="traces directory written by `ngpmc traces` (several: "
        "comma-separated, trained on together)",
    )
    p.add_argument(
        "-o",
        "--out",
        required=True,
        type=argtypes.output_file(".pt"),
        help="model file to write (model.pt)",
    )
    p.add_argument(
        "--features", default="all", choices=FEATURE_SETS, help="feature set (default all)"
    )
    p.add_argument(
        "--K",
        type=argtypes.integer(1, argtypes.MAX_K),
        default=4,
        help=f"mixture components (default 4, at most {argtypes.MAX_K})",
    )
    p.add_argument(
        "--hidden",
        type=argtypes.integer(0, argtypes.MAX_HIDDEN),
        default=0,
        help="hidden units per site network (default 0: half its inputs, >= 8; "
        f"at most {argtypes.MAX_HIDDEN})",
    )
    p.add_argument(
        "--epochs", type=argtypes.count, default=40, help="most training epochs (default 40)"
    )
    p.add_argument(
        "--batch-size", type=argtypes.count, default=256, help="site visits per step (default 256)"
    )
    p.add_argument(
        "--lr",
        type=argtypes.positive_number(1.0),
        default=0.005,
        help="Adam step size, above 0 and at most 1 (default 0.005)",
    )
    p.add_argument(
        "--patience",
        type=argtypes.count,
        default=4,
        help="early-stopping patience in epochs (default 4)",
    )
    p.add_argument("--seed", type=argtypes.seed, default=0, help="seed (default 0)")
    p.add_argument("--threads", type=argtypes.workers, default=1, help="torch threads (default 1)")
    p.add_argument(
        "--allow-missing",
        action="store_true",
        help="train even if shards listed in the manifest are missing or unreadable",
    )
    p.set_defaults(handler=cmd_train)


def _register_iterate(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser(
        "iterate",
        help="expert iteration: guided traces -> train -> repeat, keep the best",
        description="Rounds of: record traces with SMC guided by the best guide so far, train "
        "a guide on all rounds' traces, score it on validation targets at N = 10 "
        "with the default proposal settings (a tuned --init-guide is scored untuned "
        "too, so rounds compare under equal settings); the best round's guide is "
        "copied to OUT/best.onnx.",
    )
    p.add_argument("grammar", help=GRAMMAR_HELP)
    p.add_argument(
        "--targets",
        type=argtypes.paths,
        help="training-target directories, comma-separated (default none: the shape "
        "likelihood needs them, the circuit likelihood takes none)",
    )
    p.add_argument(
        "--validate",
        type=argtypes.pairs,
        help="validation sets NAME=DIR,... (targets never trained on; default none: the "
        "shape likelihood needs them, the circuit likelihood scores blank canvases)",
    )
    add_likelihood_argument(p)
    p.add_argument(
        "-o", "--out", required=True, type=argtypes.path, help="work directory (resumed if present)"
    )
    p.add_argument("--rounds", type=argtypes.count, default=2, help="rounds (default 2)")
    p.add_argument(
        "-n",
        type=argtypes.count,
        default=300,
        help="traces per round and target directory (default 300)",
    )
    p.add_argument(
        "--particles", type=argtypes.particles, default=200, help="guided particles (default 200)"
    )
    p.add_argument(
        "--unguided-particles",
        type=argtypes.particles,
        default=600,
        help="particles of a round without a guide (default 600)",
    )
    p.add_argument(
        "--init-guide",
        type=argtypes.path,
        help="guide .onnx of round 0 (default: none, round 1 is unguided)",
    )
    p.add_argument(
        "--init-traces",
        type=argtypes.paths,
        default=(),
        help="traces directories added to every round's training, comma-separated (default: none)",
    )
    p.add_argument(
        "--val-targets",
        type=argtypes.count,
        default=12,
        help="targets per validation set (default 12)",
    )
    p.add_argument(
        "--val-repeats",
        type=argtypes.count,
        default=2,
        help="runs per validation target (default 2)",
    )
    p.add_argument(
        "--features",
        default="all",
        choices=FEATURE_SETS,
        help="feature set of every round's guide (default all)",
    )
    p.add_argument(
        "--epochs", type=argtypes.count, default=40, help="most training epochs (default 40)"
    )
    argtypes.add_workers(p)
    p.add_argument("--seed", type=argtypes.seed, default=0, help="base seed (default 0)")
    add_min_primitives(p)
    p.set_defaults(handler=cmd_iterate)


# `ngpmc tune`'s default grid of proposal settings (learning/tune.py)
TUNE_GRID: dict[str, tuple[float | None, ...]] = {
    "temperature": (1.0,),
    "choice_temperature": TUNE_CHOICES[0][0],
    "ess_threshold": TUNE_CHOICES[0][1],
}


def _register_tune(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    def listed(values: tuple[float | None, ...]) -> str:
        return ",".join("none" if v is None else f"{v:g}" for v in values)

    p = subparsers.add_parser(
        "tune",
        help="choose a guide's proposal temperatures and ESS threshold on validation targets",
        description="Score guided SMC (N = 10) on validation targets for every combination of "
        "the settings below and write a copy of the guide that proposes with the "
        "best one (its metadata; `grow`, `eval`, `traces` and the web page use it). "
        "Weights stay exact with every setting.",
    )
    p.add_argument("grammar", help=GRAMMAR_HELP)
    p.add_argument("guide", help="guide .onnx written by `ngpmc export`")
    p.add_argument(
        "--validate",
        type=argtypes.pairs,
        help="validation sets NAME=DIR,... (targets never trained on, not held out; "
        "default none: the shape likelihood needs them, the circuit likelihood scores "
        "--targets blank canvases instead)",
    )
    add_likelihood_argument(p)
    p.add_argument(
        "-o",
        "--out",
        required=True,
        type=argtypes.output_file(".onnx"),
        help="tuned guide .onnx to write",
    )
    p.add_argument(
        "--work",
        type=argtypes.path,
        help="runs and candidates, resumed if present (default: OUT without .onnx, plus _tune)",
    )
    p.add_argument(
        "--temperatures",
        type=argtypes.temperatures,
        default=TUNE_GRID["temperature"],
        help="continuous-value temperatures, comma-separated (default "
        f"{listed(TUNE_GRID['temperature'])})",
    )
    p.add_argument(
        "--choice-temperatures",
        type=argtypes.temperatures,
        default=TUNE_GRID["choice_temperature"],
        help=f"choice temperatures (default {listed(TUNE_GRID['choice_temperature'])}; "
        "< 1 is sharper; 0.05 to 20)",
    )
    p.add_argument(
        "--ess",
        type=argtypes.ess_thresholds,
        default=TUNE_GRID["ess_threshold"],
        help="ESS thresholds as fractions of N, 'none' = resample every step "
        f"(default {listed(TUNE_GRID['ess_threshold'])})",
    )
    p.add_argument(
        "--targets",
        type=argtypes.count,
        default=36,
        help="targets per set (default 36; all of a smaller set)",
    )
    p.add_argument("--repeats", type=argtypes.count, default=5, help="runs per target (default 5)")
    argtypes.add_workers(p)
    p.add_argument("--seed", type=argtypes.seed, default=0, help="base seed (default 0)")
    p.set_defaults(handler=cmd_tune)


def cmd_tune(args: argparse.Namespace) -> int:
    from ngpm_runtime.inference.guide import Guide

    from ngpm_compiler.cli.outpaths import check_output_file
    from ngpm_compiler.evaluation.heldout import CIRCUIT_SETS
    from ngpm_compiler.language.compile import load_grammar
    from ngpm_compiler.learning.tune import grid, tune

    check_output_file(args.out, "ONNX file")
    check_targets_option(args.likelihood, args.validate is not None, "--validate")
    validation = args.validate if args.likelihood == "shape" else CIRCUIT_SETS
    for path in validation.values() if args.likelihood == "shape" else ():
        if not Path(path).is_dir():
            raise NgpmError(f"{path}: no such directory of validation targets")
    Guide.load(args.guide, load_grammar(args.grammar))  # names a wrong or corrupt file first
    settings = grid(args.temperatures, args.choice_temperatures, args.ess)
    work = args.work or str(Path(args.out).with_suffix("")) + "_tune"
    res = tune(
        args.grammar,
        args.guide,
        validation,
        args.out,
        work,
        settings,
        k=args.targets,
        repeats=args.repeats,
        workers=args.workers,
        seed=args.seed,
        log=_log,
        likelihood=args.likelihood,
    )
    print(res["table"], end="")
    print(f"{args.out}: proposes with {res['best'].label()} (runs in {work})")
    return 0


# --------------------------------------------------------------------------- traces / train


def add_backend_arguments(p: argparse.ArgumentParser) -> None:
    """--backend and --ray-address (traces and eval)."""
    p.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="where jobs run: local worker processes (default) or Ray tasks "
        "(a local Ray instance with --workers CPUs, or --ray-address's "
        "cluster; needs `pip install ray`)",
    )
    p.add_argument(
        "--ray-address",
        metavar="ADDRESS",
        help="a running Ray cluster (e.g. 10.0.0.1:6379 from `ray start --head`, "
        "or 'auto'); default: $RAY_ADDRESS, else a local Ray instance",
    )


def add_likelihood_argument(p: argparse.ArgumentParser) -> None:
    """--likelihood shape|circuit (traces, iterate and tune)."""
    p.add_argument(
        "--likelihood",
        choices=("shape", "circuit"),
        default="shape",
        help="shape: match target images (default); circuit: the paper's circuit-like "
        "density, no targets (runs start at the bottom middle of the viewport, heading up)",
    )


def check_targets_option(likelihood: str, given: bool, flag: str) -> None:
    """One-line errors: the shape likelihood needs `flag`, the circuit likelihood has none."""
    if likelihood == "shape" and not given:
        raise NgpmError(f"the shape likelihood needs {flag} (or use --likelihood circuit)")
    if likelihood == "circuit" and given:
        raise NgpmError(
            f"the circuit likelihood has no targets: drop {flag} (its runs start at the "
            "bottom middle of the viewport, heading up)"
        )


def cmd_traces(args: argparse.Namespace) -> int:
    from ngpm_compiler.learning.traces import TraceConfig, generate_traces

    if not args.own_samples:
        check_targets_option(args.likelihood, args.targets is not None, "--targets")
    if args.likelihood == "circuit" and args.mirror:
        raise NgpmError("--mirror mirrors targets: the circuit likelihood has none")
    cfg = TraceConfig(
        grammar=args.grammar,
        targets=args.targets or "",
        likelihood=args.likelihood,
        n=args.n,
        particles=1 if args.own_samples else args.particles,
        seed=args.seed,
        workers=args.workers,
        mirror=args.mirror,
        size=args.size,
        shard_size=args.shard_size,
        max_modules=args.max_modules,
        backend=args.backend,
        ray_address=args.ray_address,
        guide=args.guide,
        min_primitives=args.min_primitives,
        sigma=args.sigma,
        own_samples=args.own_samples,
    )
    if args.guide is not None and not Path(args.guide).is_file():
        raise NgpmError(f"--guide {args.guide}: no such file")
    m = generate_traces(cfg, args.out)
    per = np.mean(m["job_seconds"]) if m["job_seconds"] else 0.0
    failed = f", {m['failed']} of them SMC failures" if m["failed"] else ""
    short = "no" if cfg.min_primitives == 1 else f"fewer than {cfg.min_primitives}"
    print(
        f"{args.out}: {m['kept']} traces kept, {m['dropped']} dropped ({short} "
        f"primitives{failed}), {len(m['shards'])} shards, {per:.2f} s per job"
    )
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from ngpm_compiler.cli.outpaths import check_output_file
    from ngpm_compiler.learning.rounds import merge_traces
    from ngpm_compiler.learning.trace_data import load_traces
    from ngpm_compiler.learning.train import TrainConfig, save_model, train_guide

    check_output_file(args.out, "model file")
    sets = [load_traces(d, allow_missing=args.allow_missing) for d in args.traces]
    ts = sets[0] if len(sets) == 1 else merge_traces(sets)
    if not ts.data:
        raise NgpmError(f"{','.join(args.traces)}: holds no site visits to train on")
    cfg = TrainConfig(
        feature_set=args.features,
        K=args.K,
        epochs=args.epochs,
        batch_size=args.batch_size,
        lr=args.lr,
        patience=args.patience,
        seed=args.seed,
        threads=args.threads,
        hidden=args.hidden,
    )
    out = Path(args.out)
    ckpt = out.with_name(out.name + ".ckpt")
    model = train_guide(
        ts.sites,
        ts.layouts,
        ts.data,
        cfg,
        grammar=ts.manifest["key"]["grammar"],
        grammar_hash=ts.manifest["grammar_hash"],
        checkpoint=ckpt,
        progress=True,
        on_epoch=_print_epoch,
    )
    save_model(model, out)
    ckpt.unlink(missing_ok=True)
    s = model.summary
    print(
        f"{out}: {len(model.nets)} site networks, {s['traces']} traces "
        f"({s['val_traces']} held out), best epoch {s['best_epoch']} of {s['epochs_run']}, "
        f"validation NLL {s['val_nll']:.3f} per trace, {s['seconds']:.1f} s"
    )
    unseen = [x["id"] for x in model.sites if x["index"] not in model.nets]
    if unseen:
        print(f"sites unseen in training (prior fallback): {', '.join(unseen)}")
    return 0


def cmd_iterate(args: argparse.Namespace) -> int:
    from ngpm_compiler.evaluation.heldout import CIRCUIT_SETS
    from ngpm_compiler.learning.rounds import RoundsConfig, expert_iteration

    check_targets_option(args.likelihood, args.targets is not None, "--targets")
    check_targets_option(args.likelihood, args.validate is not None, "--validate")
    inits = list(args.init_traces)
    guide = [args.init_guide] if args.init_guide else []
    if args.likelihood == "circuit":  # blank canvases (rounds.RoundsConfig.likelihood)
        split, validation = [""], dict(CIRCUIT_SETS)
        inputs = [*inits, *guide]
    else:
        split, validation = list(args.targets), args.validate
        inputs = [*split, *inits, *validation.values(), *guide]
    for path in inputs:
        if not Path(path).exists():
            raise NgpmError(f"{path}: no such file or directory")
    cfg = RoundsConfig(
        grammar=args.grammar,
        targets=split,
        validation=validation,
        out=args.out,
        rounds=args.rounds,
        n=args.n,
        particles=args.particles,
        unguided_particles=args.unguided_particles,
        init_guide=args.init_guide,
        init_traces=inits,
        val_targets=args.val_targets,
        val_repeats=args.val_repeats,
        feature_set=args.features,
        epochs=args.epochs,
        workers=args.workers,
        seed=args.seed,
        min_primitives=args.min_primitives,
        likelihood=args.likelihood,
    )
    rows = expert_iteration(cfg, log=_log)
    print("| round | teacher | traces | validation NLL | validation similarity (N=10) |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['round']} | {r['teacher']} | {r['traces']} | {r['val_nll']} | "
            f"{r['validation']} |"
        )
    return 0


def _log(text: str) -> None:
    import time

    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


def _print_epoch(row: dict[str, Any]) -> None:
    from tqdm import tqdm

    tqdm.write(
        f"epoch {row['epoch']}: train NLL {row['train_nll']:.3f}, "
        f"validation NLL {row['val_nll']:.3f} per trace"
    )


def cmd_export(args: argparse.Namespace) -> int:
    from ngpm_compiler.cli.outpaths import check_output_file
    from ngpm_compiler.learning.export import write_onnx
    from ngpm_compiler.learning.train import load_model_file

    check_output_file(args.out, "ONNX file")
    model = load_model_file(args.model)
    path = write_onnx(model, args.out)
    print(
        f"{path}: {len(model.nets)} site networks, features {model.feature_set}, "
        f"K {model.K}, {path.stat().st_size} bytes"
    )
    unseen = [x["id"] for x in model.sites if x["index"] not in model.nets]
    if unseen:
        print(f"sites without a network (prior fallback): {', '.join(unseen)}")
    return 0
