"""`ngpmc traces`, `train`, `export` and `grow`: learned guides, from traces to guided SMC."""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.program import Program

FEATURE_SETS = ("const", "local", "local+target", "all")  # = nets.FEATURE_SETS (no torch here)


class GuideFileError(NgpmError):
    """A model.pt file cannot be read."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("traces", help="record training traces with unguided SMC")
    p.add_argument("grammar", help="the .lsys file (or a generated *_sampler.py)")
    p.add_argument("--targets", required=True, help="dataset directory of target images")
    p.add_argument("-n", type=int, default=1000, help="traces to keep (default 1000)")
    p.add_argument("--particles", type=int, default=600, help="SMC particles (default 600)")
    p.add_argument("-o", "--out", required=True, help="traces directory (resumed if present)")
    p.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    p.add_argument("--mirror", action="store_true",
                   help="add mirrored copies of targets that have none")
    p.add_argument("--size", type=int, default=50, help="target size in pixels (default 50)")
    p.add_argument("--shard-size", type=int, default=50, help="jobs per shard (default 50)")
    p.set_defaults(handler=cmd_traces)

    p = subparsers.add_parser("train", help="train guide networks on recorded traces")
    p.add_argument("traces", help="traces directory written by `ngpmc traces`")
    p.add_argument("-o", "--out", required=True, help="model file to write (model.pt)")
    p.add_argument("--features", default="all", choices=FEATURE_SETS,
                   help="feature set (default all)")
    p.add_argument("--K", type=int, default=4, help="mixture components (default 4)")
    p.add_argument("--epochs", type=int, default=40, help="most epochs (default 40)")
    p.add_argument("--batch-size", type=int, default=256, help="site visits per step")
    p.add_argument("--lr", type=float, default=0.005, help="Adam step size (default 0.005)")
    p.add_argument("--patience", type=int, default=4, help="early-stopping patience (epochs)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.set_defaults(handler=cmd_train)

    p = subparsers.add_parser("export", help="export a trained guide to one ONNX file")
    p.add_argument("model", help="model file written by `ngpmc train`")
    p.add_argument("-o", "--out", required=True, help="ONNX file to write")
    p.set_defaults(handler=cmd_export)

    p = subparsers.add_parser("grow", help="grow a grammar into a target with SMC")
    p.add_argument("grammar", help="the .lsys file (or a generated *_sampler.py)")
    p.add_argument("--target", required=True, help="target image (with its .txt sidecar)")
    p.add_argument("--guide", help="guide .onnx (default: unguided, prior proposals)")
    p.add_argument("-N", "--particles", type=int, default=10, help="particles (default 10)")
    p.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    p.add_argument("--size", type=int, default=50, help="target size in pixels (default 50)")
    p.add_argument("-o", "--out", help="render of the best particle (.png or .svg)")
    p.set_defaults(handler=cmd_grow)


# --------------------------------------------------------------------------- traces / train


def cmd_traces(args: argparse.Namespace) -> int:
    from ngpm_compiler.traces import TraceConfig, generate_traces

    if args.n < 1 or args.particles < 1 or args.workers < 1:
        raise NgpmError("-n, --particles and --workers must be at least 1")
    cfg = TraceConfig(grammar=args.grammar, targets=args.targets, n=args.n,
                      particles=args.particles, seed=args.seed, workers=args.workers,
                      mirror=args.mirror, size=args.size, shard_size=max(1, args.shard_size))
    m = generate_traces(cfg, args.out)
    per = np.mean(m["job_seconds"]) if m["job_seconds"] else 0.0
    failed = f", {m['failed']} of them SMC failures" if m["failed"] else ""
    print(f"{args.out}: {m['kept']} traces kept, {m['dropped']} dropped (fewer than "
          f"{cfg.min_primitives} primitives{failed}), {len(m['shards'])} shards, "
          f"{per:.2f} s per job")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from ngpm_compiler.traces import load_traces
    from ngpm_compiler.train import TrainConfig, save_model, train_guide

    ts = load_traces(args.traces)
    if not ts.data:
        raise NgpmError(f"{args.traces}: holds no site visits to train on")
    cfg = TrainConfig(feature_set=args.features, K=args.K, epochs=args.epochs,
                      batch_size=args.batch_size, lr=args.lr, patience=args.patience,
                      seed=args.seed, threads=args.threads)
    out = Path(args.out)
    ckpt = out.with_name(out.name + ".ckpt")
    model = train_guide(ts.sites, ts.layouts, ts.data, cfg,
                        grammar=ts.manifest["key"]["grammar"],
                        grammar_hash=ts.manifest["grammar_hash"], checkpoint=ckpt,
                        progress=True, on_epoch=_print_epoch)
    save_model(model, out)
    ckpt.unlink(missing_ok=True)
    s = model.summary
    print(f"{out}: {len(model.nets)} site networks, {s['traces']} traces "
          f"({s['val_traces']} held out), best epoch {s['best_epoch']} of {s['epochs_run']}, "
          f"validation NLL {s['val_nll']:.3f} per trace, {s['seconds']:.1f} s")
    unseen = [x["id"] for x in model.sites if x["index"] not in model.nets]
    if unseen:
        print(f"sites unseen in training (prior fallback): {', '.join(unseen)}")
    return 0


def _print_epoch(row: dict[str, Any]) -> None:
    from tqdm import tqdm

    tqdm.write(f"epoch {row['epoch']}: train NLL {row['train_nll']:.3f}, "
               f"validation NLL {row['val_nll']:.3f} per trace")


def load_model_file(path: str) -> Any:
    from ngpm_compiler.train import load_model

    if not Path(path).is_file():
        raise GuideFileError(f"{path}: no such model file")
    try:
        return load_model(path)
    except Exception as err:  # torch raises many types for foreign files
        raise GuideFileError(f"{path}: not a model written by `ngpmc train` "
                             f"({err.__class__.__name__})") from None


def cmd_export(args: argparse.Namespace) -> int:
    from ngpm_compiler.export import write_onnx

    model = load_model_file(args.model)
    path = write_onnx(model, args.out)
    print(f"{path}: {len(model.nets)} site networks, features {model.feature_set}, "
          f"K {model.K}, {path.stat().st_size} bytes")
    unseen = [x["id"] for x in model.sites if x["index"] not in model.nets]
    if unseen:
        print(f"sites without a network (prior fallback): {', '.join(unseen)}")
    return 0


# --------------------------------------------------------------------------- grow


@dataclass
class GrowResult:
    similarity: float
    seconds: float
    particles: int
    primitives: list[tuple]
    image: np.ndarray  # (H, W) uint8 raster of the best particle
    smc: Any  # the SMCResult


def grow(program: Program, target: Any, guide: Any = None, n_particles: int = 10,
         seed: int = 0) -> GrowResult:
    """SMC (guided when `guide` is given) into `target`; the best particle and its score."""
    from ngpm_runtime.likelihood import ShapeLikelihood, similarity
    from ngpm_runtime.raster import rasterize
    from ngpm_runtime.smc import smc

    viewport = program.viewport
    if viewport is None:
        raise NgpmError(f"grammar {program.name} has no viewport: cannot grow into a target")
    t0 = time.perf_counter()
    result = smc(program, ShapeLikelihood(target.mask, viewport), n_particles, proposal=guide,
                 seed=seed, start=target.start_pose(viewport), canvas_size=target.size,
                 target_mask=target.mask)
    seconds = time.perf_counter() - t0
    prims = list(result.best.primitives)
    image = rasterize(prims, viewport, *target.size)
    return GrowResult(float(similarity(image, target.mask)), seconds, n_particles, prims,
                      image, result)


def cmd_grow(args: argparse.Namespace) -> int:
    from ngpm_runtime.guide import Guide
    from ngpm_runtime.targets import load_target

    from ngpm_compiler.traces import load_grammar

    if args.particles < 1:
        raise NgpmError("-N must be at least 1")
    if not Path(args.grammar).is_file():
        raise NgpmError(f"{args.grammar}: no such grammar file")
    program = load_grammar(args.grammar)
    target = load_target(args.target, size=args.size)
    guide = None
    if args.guide:
        guide = Guide.load(args.guide, program)
        if guide.fallback_sites:
            ids = ", ".join(program.sites[i].id for i in guide.fallback_sites)
            print(f"guide: {len(guide.fallback_sites)} sites unseen in training use the "
                  f"prior: {ids}")
    res = grow(program, target, guide, args.particles, args.seed)
    kind = "guided" if guide else "unguided"
    print(f"{target.name}: similarity {res.similarity:.3f}, {res.particles} particles "
          f"({kind}), {res.seconds:.2f} s, {len(res.primitives)} primitives")
    if args.out:
        from ngpm_runtime.render import save_render

        save_render(res.primitives, args.out, viewport=program.viewport,
                    target_mask=target.mask)
        print(f"wrote {args.out}")
    return 0
