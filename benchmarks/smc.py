"""SMC speed on the project's held-out targets (glyphs and silhouettes), one core.

Default: the step-cost table. Guided N=10 (the bundled guide, ngpm_runtime/data/vines_guide.onnx,
or `--guide PATH`) and unguided N=10/200/600 run interleaved (per seed, per target, every
configuration in turn) on the same targets; printed per configuration: median ms per SMC
step (CPU and wall), median seconds per run, median steps, mean similarity of the best
particle; then guided N=10's cost per step over unguided N=10's.

--equal-sim: guided N=10 against unguided SMC at a ladder of N on the same targets
(`--repeats` seeds each, seeds as `ngpmc eval`): mean over targets of the per-target median
similarity and mean CPU seconds per N; the unguided N that matches guided N=10's similarity
(log-interpolated, evaluation.runs.n_to_match) and the time ratio at that similarity
(evaluation.runs.time_to_reach): the figure docs/results reports for Fig. 4b.

--nets: one site network's call, numpy engine (guide.NumpyNet) against onnxruntime, by rows.
--profile: where a guided N=10 step's CPU time goes: per part of the SMC loop (wrapped
with CPU timers, which add ~1 us per call), calls per step and us per call; then cProfile's
top functions by own time.
--json PATH: the step table's every run (CPU and wall seconds, steps, similarity) as JSON,
for comparing two versions run in turn (benchmarks/compare_steps.py).
--trace-jobs: the 600-particle trace job (values recorded, best replayed) next to recording
features for every particle.
--round-kernel: guided N=10 with a round in one kernels.serve_round call against the
round's separate calls, alternating run by run in one process (`--repeats` rounds).
--compiled: guided N=10, unguided N=200/600/2000 and the 600-particle trace job on the
compiled deriver (inference/compiled_run.py) against the Python deriver, alternating run by
run.

Usage: python benchmarks/smc.py [--guide PATH] [--glyphs 6] [--silhouettes 6] [--seeds 2]
       [--equal-sim [--ladder 10,20,...] [--repeats 3]] [--nets] [--profile] [--trace-jobs]
       [--round-kernel [--repeats 3]] [--compiled [--repeats 3]]
Needs the compiler (ngpm_compiler) for the datasets. CPU seconds are reported as well as
wall seconds: the machine may be shared.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
STEP_CONFIGS = (
    ("guided N=10", True, 10),
    ("unguided N=10", False, 10),
    ("unguided N=200", False, 200),
    ("unguided N=600", False, 600),
    ("unguided N=2000", False, 2000),
)
LADDER = "10,20,50,100,200,400,600,1000,1500"


def held_out_targets(n_glyphs: int, n_silhouettes: int) -> list[tuple[str, Any]]:
    """(dataset, target) pairs: glyphs and silhouettes spread over each set as `ngpmc eval`
    picks its test targets (eval_shape.pick; mirrored copies left out), 50x50."""
    from ngpm_runtime.image.targets import load_dataset

    from ngpm_compiler.datasets.build import build_dataset
    from ngpm_compiler.experiments.shape import pick

    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, k in (("glyphs", n_glyphs), ("silhouettes", n_silhouettes)):
            if k <= 0:
                continue
            d = Path(tmp) / name
            build_dataset(name, d, count=None, seed=0)
            ts = [t for t in load_dataset(d, size=50) if not t.name.endswith("_m")]
            out += [(name, t) for t in pick(ts, k)]
    return out


def one_run(program: Any, target: Any, proposal: Any, n: int, seed: int) -> dict[str, float]:
    from ngpm_runtime.image.raster import rasterize
    from ngpm_runtime.inference.likelihood import ShapeLikelihood, similarity
    from ngpm_runtime.inference.smc import SMCOptions, smc

    vp = program.viewport
    t0, c0 = time.perf_counter(), time.process_time()
    res = smc(
        program,
        ShapeLikelihood(target.mask, vp),
        n,
        proposal,
        options=SMCOptions(
            ess_from_proposal=True,
            seed=seed,
            start=target.start_pose(vp),
            canvas_size=target.size,
            target_mask=target.mask,
        ),
    )
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    sim = similarity(rasterize(res.best.primitives, vp, *target.size), target.mask)
    return {
        "wall": wall,
        "cpu": cpu,
        "steps": res.steps,
        "particle_steps": res.info["particle_steps"],
        "sim": float(sim),
    }


def step_table(
    program: Any, guide: Any, targets: list, seeds: int, json_path: str | None = None
) -> None:
    """The interleaved step-cost table (and every run's figures to `json_path`)."""
    rows: dict[str, list[dict[str, float]]] = {label: [] for label, _, _ in STEP_CONFIGS}
    for _, t in targets[:2]:  # warm-up (imports, caches)
        one_run(program, t, guide, 10, 99)
        one_run(program, t, None, 10, 99)
    for seed in range(seeds):
        for _, t in targets:
            for label, guided, n in STEP_CONFIGS:
                rows[label].append(one_run(program, t, guide if guided else None, n, seed))
    if json_path:
        Path(json_path).write_text(json.dumps(rows))
    print(
        f"\nstep cost: {len(targets)} held-out targets x {seeds} seeds, interleaved; medians "
        "over runs (ms/step = run time / SMC steps)"
    )
    print(
        f"{'':16s} {'ms/step CPU':>11s} {'ms/step wall':>12s} {'s/run wall':>10s} "
        f"{'s/run CPU':>9s} {'steps':>5s} {'us/particle-step':>16s} {'similarity':>10s}"
    )
    per_step: dict[str, float] = {}
    for label, rs in rows.items():
        cpu_step = statistics.median(1000 * r["cpu"] / r["steps"] for r in rs)
        per_step[label] = cpu_step
        print(
            f"{label:16s} {cpu_step:11.3f} "
            f"{statistics.median(1000 * r['wall'] / r['steps'] for r in rs):12.3f} "
            f"{statistics.median(r['wall'] for r in rs):10.4f} "
            f"{statistics.median(r['cpu'] for r in rs):9.4f} "
            f"{statistics.median(r['steps'] for r in rs):5.0f} "
            f"{statistics.median(1e6 * r['cpu'] / r['particle_steps'] for r in rs):16.1f} "
            f"{statistics.mean(r['sim'] for r in rs):10.3f}"
        )
    ratio = per_step["guided N=10"] / per_step["unguided N=10"]
    print(f"guided N=10 per step / unguided N=10 per step (CPU): {ratio:.2f}x")


def equal_similarity(
    program: Any, guide: Any, targets: list, ladder: list[int], repeats: int
) -> None:
    """Guided N=10 vs the unguided ladder: crossing N and time ratio (evaluation/runs.py)."""
    from ngpm_compiler.evaluation.runs import (
        curve,
        match_text,
        n_to_match,
        run_seed,
        summarize,
        time_to_reach,
    )

    rows = []
    for rep in range(repeats):
        for ti, (ds, t) in enumerate(targets):
            for model, proposal, ns in (("all", guide, [10]), ("unguided", None, ladder)):
                for n in ns:
                    r = one_run(program, t, proposal, n, run_seed(0, ti, n, rep))
                    # CPU seconds: the machine is shared, and wall time counts the others
                    rows.append(
                        {
                            "model": model,
                            "n": n,
                            "dataset": ds,
                            "target": t.name,
                            "similarity": r["sim"],
                            "seconds": r["cpu"],
                        }
                    )
    print(
        f"\nequal similarity: {len(targets)} held-out targets x {repeats} repeats; mean over "
        "targets of the per-target median similarity, mean CPU seconds per run"
    )
    for ds in sorted({r["dataset"] for r in rows}) + ["all"]:
        sub = [r for r in rows if ds == "all" or r["dataset"] == ds]
        summary = summarize(sub, ds)
        g = next(r for r in summary if r["model"] == "all")
        ns, sims, secs = curve(summary, "unguided")
        table = ", ".join(
            f"{n}: {s:.3f} ({t:.2f} s)"
            for n, s, t in zip(ns.tolist(), sims.tolist(), secs.tolist(), strict=True)
        )
        cross = n_to_match(summary, g["mean_similarity"])
        t_u = time_to_reach(sims, secs, g["mean_similarity"])
        where, ratio = match_text(cross, t_u, g["mean_seconds"], ns, secs)
        print(
            f"[{ds}] guided N=10: similarity {g['mean_similarity']:.3f} in "
            f"{g['mean_seconds']:.3f} s; unguided by N: {table}"
        )
        print(
            f"[{ds}] unguided matches it at {where}: guided N=10 is {ratio} faster at "
            "equal similarity"
        )


# (module, owner, attribute, label): the parts of a guided step, outermost first
PARTS = (
    ("inference.run", "_Run", "step", "step (everything)"),
    ("inference.compiled_run", "CompiledRun", "_derive", " derive (compiled deriver): rounds"),
    ("inference.compiled_run", "CompiledRun", "_advance", "  advance (the grammar's kernel)"),
    ("round_kernels", None, "guided_round", "  outcomes, site order, packing (kernel)"),
    ("round_kernels", None, "serve_take", "  features, nets, draws, weights, values (kernel)"),
    ("inference.run", "_Run", "_derive", " derive (Python deriver): rounds"),
    ("geometry.derive", "Deriver", "advance_all", "  advance_all (the deriver, per group)"),
    ("inference.run", "_Run", "_serve", "  serve (one round's sites)"),
    ("inference.run", "_Run", "_round_rows", "   rows: gather particle state + features"),
    ("inference.run", "_Buffers", "unpack", "    unpack the state (kernel call)"),
    ("image.features", "FeatureMaker", "rows_from", "    feature rows (kernel call)"),
    ("inference.guide", "Guide", "propose_rows", "   guide: nets + draws"),
    ("inference.guide", "Guide", "_kernel", "    nets, draws, log q, log p (kernel call)"),
    ("inference.run", "_Run", "_weigh", "   apply site weights"),
    ("inference.compiled_run", "CompiledRun", "_observe", " observe (compiled deriver)"),
    ("inference.run", "_Run", "_observe", " observe (Python deriver)"),
    ("image.raster", "Canvas", "draw_packed", "  rasterize (+ pyramid)"),
    ("inference.likelihood", "ShapeLikelihood", "increment", "  likelihood increment"),
    ("inference.run", "_Run", "_resample", " resample"),
)


def breakdown(program: Any, guide: Any, targets: list) -> None:
    """CPU time per part of guided N=10 steps (wrapped timers), per step and per call."""
    import importlib

    from ngpm_runtime.inference.smc import SMCOptions, smc

    acc: dict[str, list[float]] = {}
    saved = []
    for mod, owner, attr, label in PARTS:
        m = importlib.import_module(f"ngpm_runtime.{mod}")
        obj = getattr(m, owner) if owner else m
        fn = getattr(obj, attr)
        saved.append((obj, attr, fn))
        slot = acc.setdefault(label, [0.0, 0])

        def timed(*a: Any, _fn: Any = fn, _slot: list = slot, **k: Any) -> Any:
            c0 = time.process_time()
            try:
                return _fn(*a, **k)
            finally:
                _slot[0] += time.process_time() - c0
                _slot[1] += 1

        setattr(obj, attr, timed)
    steps = 0
    try:
        for seed in range(2):
            for _, t in targets:
                steps += smc(
                    program,
                    _like(program, t),
                    10,
                    guide,
                    options=SMCOptions(
                        ess_from_proposal=True,
                        seed=seed,
                        start=t.start_pose(program.viewport),
                        canvas_size=t.size,
                        target_mask=t.mask,
                    ),
                ).steps
    finally:
        for obj, attr, fn in saved:
            setattr(obj, attr, fn)
    print(
        f"\nguided N=10, {len(targets)} targets x 2 seeds, {steps} steps: CPU per step "
        "(timers included)"
    )
    print(f"{'part':48s} {'us/step':>8s} {'calls/step':>10s} {'us/call':>8s}")
    for _, _, _, label in PARTS:
        total, calls = acc[label]
        if calls:
            print(
                f"{label:48s} {1e6 * total / steps:8.0f} {calls / steps:10.2f} "
                f"{1e6 * total / calls:8.1f}"
            )


def _like(program: Any, target: Any) -> Any:
    from ngpm_runtime.inference.likelihood import ShapeLikelihood

    return ShapeLikelihood(target.mask, program.viewport)


def nets(guide: Any) -> None:
    """One site net per call: numpy engine vs onnxruntime, by batch rows."""
    import timeit

    site = 1
    sess, numpy_net = guide.site_sessions.get(site), guide.numpy_nets.get(site)
    if sess is None or numpy_net is None:
        print("no per-site engines (onnx package missing?)")
        return
    print(f"\nsite {site} net, one call, best of 7 (us): rows, numpy, onnxruntime")
    rng = np.random.default_rng(0)
    for rows in (1, 3, 10, 100, 1000):
        x = rng.normal(size=(rows, guide.nets[site]["n_f"])).astype(np.float32)
        num = max(20, 20000 // rows)
        a = min(timeit.repeat(lambda: numpy_net(x), number=num, repeat=7)) / num  # noqa: B023
        b = (
            min(
                timeit.repeat(
                    lambda: sess.run(None, {f"f_{site}": x}),  # noqa: B023
                    number=num,
                    repeat=7,
                )
            )
            / num
        )
        print(f"{rows:5d} {1e6 * a:8.1f} {1e6 * b:8.1f}")


def round_kernel(program: Any, guide: Any, targets: list, repeats: int) -> None:
    """Guided N=10 with each round in one kernels.serve_round call against the round's
    separate calls (Guide.round_tables switched off), the two alternating run by run in
    this process (so a changing load hits both alike): median CPU ms per step of each and
    the median of the paired ratios. The runs are bit-identical, so only time differs."""
    from ngpm_runtime.inference.guide import Guide

    fused = Guide.round_tables
    ms: dict[bool, list[float]] = {True: [], False: []}
    try:
        for rep in range(repeats):
            for seed in range(2):
                for _, t in targets:
                    for on in (True, False) if (rep + seed) % 2 == 0 else (False, True):
                        Guide.round_tables = fused if on else lambda self, sites: None
                        r = one_run(program, t, guide, 10, seed)
                        ms[on].append(1000 * r["cpu"] / r["steps"])
    finally:
        Guide.round_tables = fused
    ratio = statistics.median(a / b for a, b in zip(ms[False], ms[True], strict=True))
    print(
        f"\nround kernel: guided N=10, {len(ms[True])} runs each, alternating: "
        f"{statistics.median(ms[False]):.3f} ms/step CPU with the separate calls, "
        f"{statistics.median(ms[True]):.3f} with serve_round; paired ratio {ratio:.2f}x"
    )


def compiled_deriver(program: Any, guide: Any, targets: list, repeats: int) -> None:
    """Guided N = 10, unguided SMC (N = 200, 600, 2000) and the 600-particle trace job on
    the compiled deriver (inference/compiled_run.py) against the Python deriver
    (smc.USE_COMPILED off), alternating run by run in this process: median CPU seconds per
    run of each, the
    median of the paired ratios, and whether every pair gave the same similarity (the
    runs are bit-identical)."""
    from ngpm_runtime.inference import smc as smc_module

    from ngpm_compiler.learning.trace_jobs import run_job

    one_run(program, targets[0][1], None, smc_module.COMPILE_FROM, 0)  # compile, load
    print(f"\ncompiled deriver vs Python deriver, alternating, {repeats} repeat(s):")
    print(f"{'':22s} {'Python s':>9s} {'compiled s':>10s} {'ratio':>6s} {'equal':>6s}")
    labels = ("guided N=10", "unguided N=200", "unguided N=600", "unguided N=2000")
    for label in labels + ("trace job N=600",):
        secs: dict[bool, list[float]] = {True: [], False: []}
        same = True
        for rep in range(repeats):
            for ti, (_, t) in enumerate(targets):
                sims = []
                for on in (True, False) if (rep + ti) % 2 == 0 else (False, True):
                    smc_module.USE_COMPILED = on
                    try:
                        if label.startswith("trace"):
                            c0 = time.process_time()
                            trace, n_prims = run_job(program, t, rep, 600)
                            secs[on].append(time.process_time() - c0)
                            sims.append(repr((n_prims, [(s, v) for s, _, v in trace])))
                        else:
                            n = int(label.split("=")[1])
                            r = one_run(program, t, guide if n == 10 else None, n, rep)
                            secs[on].append(r["cpu"])
                            sims.append(repr(r["sim"]))
                    finally:
                        smc_module.USE_COMPILED = True
                same = same and sims[0] == sims[1]
        ratio = statistics.median(b / a for a, b in zip(secs[True], secs[False], strict=True))
        print(
            f"{label:22s} {statistics.median(secs[False]):9.4f} "
            f"{statistics.median(secs[True]):10.4f} {ratio:5.2f}x {str(same):>6s}"
        )


def trace_jobs(program: Any, targets: list) -> None:
    """The 600-particle trace job (traces.run_job) and the same run with features for
    every particle (trace=TraceRecording.FULL), CPU seconds per job."""
    from ngpm_runtime.inference.likelihood import ShapeLikelihood
    from ngpm_runtime.inference.smc import SMCOptions, TraceRecording, smc

    from ngpm_compiler.learning.trace_jobs import run_job

    vp = program.viewport
    job, full = [], []
    for _, t in targets:
        c0 = time.process_time()
        run_job(program, t, 5, 600)
        c1 = time.process_time()
        smc(
            program,
            ShapeLikelihood(t.mask, vp),
            600,
            options=SMCOptions(
                seed=5,
                trace=TraceRecording.FULL,
                start=t.start_pose(vp),
                canvas_size=t.size,
                target_mask=t.mask,
            ),
        )
        c2 = time.process_time()
        job.append(c1 - c0)
        full.append(c2 - c1)
    print(
        f"\ntrace job, 600 particles: {statistics.mean(job):.3f} CPU s per job (values "
        f"recorded, best replayed) vs {statistics.mean(full):.3f} with features for every "
        f"particle; mean over {len(targets)} targets"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--guide", default=None, help="guide .onnx (default: the bundled one)")
    ap.add_argument("--glyphs", type=int, default=6)
    ap.add_argument("--silhouettes", type=int, default=6)
    ap.add_argument("--seeds", type=int, default=2, help="seeds per target, step table")
    ap.add_argument("--equal-sim", action="store_true")
    ap.add_argument("--ladder", default=LADDER, help="unguided N for --equal-sim")
    ap.add_argument("--repeats", type=int, default=3, help="repeats per target, --equal-sim")
    ap.add_argument("--nets", action="store_true")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--trace-jobs", action="store_true")
    ap.add_argument("--round-kernel", action="store_true")
    ap.add_argument("--compiled", action="store_true")
    ap.add_argument("--json", default=None, help="write the step table's runs here")
    args = ap.parse_args()

    from ngpm_runtime.bundled import bundled_program, guide_path
    from ngpm_runtime.inference.guide import Guide

    program = bundled_program()
    path = args.guide or str(guide_path())
    guide = Guide.load(path, program)
    targets = held_out_targets(args.glyphs, args.silhouettes)
    print(
        f"vines, guide {Path(path).name}, {len(targets)} held-out targets "
        f"({args.glyphs} glyphs, {args.silhouettes} silhouettes), one core, "
        f"{os.cpu_count()} CPUs on the machine"
    )
    if args.profile:
        breakdown(program, guide, targets)
        prof = cProfile.Profile()
        prof.enable()
        for _, t in targets:
            one_run(program, t, guide, 10, 0)
        prof.disable()
        pstats.Stats(prof, stream=sys.stdout).sort_stats("tottime").print_stats(25)
        return
    if args.nets:
        nets(guide)
    if args.round_kernel:
        round_kernel(program, guide, targets, args.repeats)
        return
    if args.compiled:
        compiled_deriver(program, guide, targets, args.repeats)
        return
    step_table(program, guide, targets, args.seeds, args.json)
    if args.equal_sim:
        equal_similarity(
            program, guide, targets, [int(x) for x in args.ladder.split(",")], args.repeats
        )
    if args.trace_jobs:
        trace_jobs(program, targets[:6])


if __name__ == "__main__":
    main()
