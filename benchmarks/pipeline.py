"""Learned-guide pipeline figures on this machine: traces, training, guided SMC.

    python3 benchmarks/pipeline.py [--traces 40] [--particles 600] [--workers 2] [--out DIR]

Prints seconds per 600-particle trace (one process), the wall time for N traces on
`--workers` processes and its extrapolation to 1000 (goal <= 10 min), the training time on
them and its extrapolation to 1000 traces (goal <= 2 min), and seconds per guided N=10 result
(goal <= 0.05 s) next to unguided N=10, on held-out scribbles; `--ablation` adds the
paper's feature-set and K=1 ablation. The machine may be shared: figures can be inflated.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from ngpm_runtime.grow import grow
from ngpm_runtime.inference.guide import Guide

from ngpm_compiler.datasets.build import build_dataset
from ngpm_compiler.language.compile import load_grammar
from ngpm_compiler.learning.export import write_onnx
from ngpm_compiler.learning.trace_data import load_traces
from ngpm_compiler.learning.trace_jobs import job_spec, load_targets, run_job
from ngpm_compiler.learning.traces import TraceConfig, generate_traces
from ngpm_compiler.learning.train import TrainConfig, train_guide

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grammar", default=str(ROOT / "grammars" / "vines.lsys"))
    ap.add_argument("--traces", type=int, default=40, help="traces to generate (N)")
    ap.add_argument("--particles", type=int, default=600)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--targets", type=int, default=60, help="scribble targets (+ mirrored)")
    ap.add_argument("--grow", type=int, default=20, help="held-out targets to grow into")
    ap.add_argument(
        "--ablation",
        action="store_true",
        help="also train const / local / local+target / all (K=4) and all (K=1)",
    )
    ap.add_argument("--out", help="work directory (default: a temporary one)")
    args = ap.parse_args()
    work = Path(args.out or tempfile.mkdtemp(prefix="ngpm_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    data = work / "scribbles"
    build_dataset("scribbles", data, count=args.targets, seed=0, mirror=True)
    program = load_grammar(args.grammar)
    targets = load_targets(data, 50, mirror=False)
    build_dataset("scribbles", work / "test", count=args.grow, seed=1)
    tests = load_targets(work / "test", 50, mirror=False)
    print(
        f"grammar {program.name}: {len(program.sites)} sites; {len(targets)} targets; "
        f"work dir {work}"
    )

    # 1. one 600-particle trace job, single process
    times, kept = [], 0
    for job in range(8):
        ti, seed = job_spec(1234, job, len(targets))
        t0 = time.perf_counter()
        _, n_prims = run_job(program, targets[ti], seed, args.particles)
        times.append(time.perf_counter() - t0)
        kept += n_prims >= 10
    per_job = statistics.mean(times)
    print(
        f"trace job ({args.particles} particles, 1 process): {per_job:.2f} s mean, "
        f"{min(times):.2f}-{max(times):.2f} s over {len(times)} jobs ({kept} kept)"
    )

    # 2. N kept traces on `workers` processes
    out = work / "traces"
    m = generate_traces(
        TraceConfig(
            grammar=args.grammar,
            targets=str(data),
            n=args.traces,
            particles=args.particles,
            workers=args.workers,
        ),
        out,
        progress=False,
    )
    wall = m["seconds"]  # summed over runs when the traces directory is resumed
    jobs = m["kept"] + m["dropped"]
    print(
        f"{m['kept']} traces ({m['dropped']} dropped, {jobs} jobs) on {args.workers} "
        f"processes: {wall:.1f} s wall = {wall / m['kept']:.2f} s per kept trace; "
        f"extrapolated to 1000 traces: {wall / m['kept'] * 1000 / 60:.1f} min (goal <= 10)"
    )

    # 3. training
    ts = load_traces(out)
    rows = sum(len(d.values) for d in ts.data.values())
    t0 = time.perf_counter()
    model = train_guide(
        ts.sites,
        ts.layouts,
        ts.data,
        TrainConfig(),
        grammar=program.name,
        grammar_hash=program.grammar_hash,
    )
    train_s = time.perf_counter() - t0
    s = model.summary
    print(
        f"training on {m['kept']} traces ({rows} site visits): {train_s:.1f} s, "
        f"{s['epochs_run']} epochs (best {s['best_epoch']}), validation NLL "
        f"{s['val_nll']:.2f} per trace; extrapolated to 1000 traces: "
        f"{train_s * 1000 / m['kept'] / 60:.2f} min (goal <= 2)"
    )

    # 4. guided vs unguided N = 10, on held-out targets
    guide = Guide.load(write_onnx(model, work / "guide.onnx"), program)
    if guide.fallback_sites:
        print(f"sites unseen in training (prior fallback): {guide.fallback_sites}")
    report("guided (all, K=4)", program, tests, guide)
    report("unguided", program, tests, None)
    if args.ablation:
        for features, K in (("const", 4), ("local", 4), ("local+target", 4), ("all", 1)):
            m2 = train_guide(
                ts.sites,
                ts.layouts,
                ts.data,
                TrainConfig(feature_set=features, K=K),
                grammar=program.name,
                grammar_hash=program.grammar_hash,
            )
            g2 = Guide.load(write_onnx(m2, work / f"guide_{features}_{K}.onnx"), program)
            report(
                f"guided ({features}, K={K})",
                program,
                tests,
                g2,
                f", validation NLL {m2.summary['val_nll']:.2f}",
            )


def report(name: str, program: object, tests: list, proposal: object, extra: str = "") -> None:
    secs, sims = [], []
    for i, target in enumerate(tests):
        r = grow(program, target, proposal, 10, seed=i)  # type: ignore[arg-type]
        secs.append(r.seconds)
        sims.append(r.similarity)
    print(
        f"{name} N=10: {statistics.mean(secs):.3f} s per result (median "
        f"{statistics.median(secs):.3f}), mean similarity {statistics.mean(sims):.3f} "
        f"over {len(secs)} held-out targets{extra}"
    )


if __name__ == "__main__":
    main()
