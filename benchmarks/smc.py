"""Unguided SMC on vines against a 50x50 filled-disk target: seconds per run and
particle-steps per second (one core); then, with a guide (`--guide PATH`, default
work/vines/vines_guide.onnx when present), guided N=10 on glyph targets: seconds per result
and proposal calls per result; and the 600-particle trace job (values recorded, best particle
replayed for its features) next to recording features for every particle.

Usage: python benchmarks/smc.py [--profile] [--guide PATH] [--targets N]

Uses the compiler's output for grammars/vines.lsys when the compiler is importable, else the
hand-written fixture tests/fixtures/vines_sampler.py (then no guided or trace figures).
CPU seconds are reported as well as wall seconds: the machine may be shared.
"""

from __future__ import annotations

import argparse
import cProfile
import math
import os
import pstats
import statistics
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def vines_program():
    from ngpm_runtime.program import load_program

    try:
        from ngpm_compiler.language.compile import compile_grammar
    except ImportError:
        return load_program(ROOT / "tests" / "fixtures" / "vines_sampler.py"), "fixture"
    return compile_grammar(str(ROOT / "grammars" / "vines.lsys")).program(), "compiled"


def disk_target(size: int = 50):
    """A filled disk in the upper middle of the image; start at its bottom, heading up."""
    from ngpm_runtime.image.targets import Target

    yy, xx = np.mgrid[0:size, 0:size]
    c = (size - 1) / 2.0
    mask = (xx - c) ** 2 + (yy - 0.4 * size) ** 2 < (0.32 * size) ** 2
    return Target(mask, (0.5, 0.75, 0.0, -1.0), "disk")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--particles", type=int, default=600)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--resample", default="residual")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--guide", default=str(ROOT / "work" / "vines" / "vines_guide.onnx"))
    ap.add_argument("--targets", type=int, default=20, help="glyph targets for guided runs")
    args = ap.parse_args()

    from ngpm_runtime.inference.likelihood import ShapeLikelihood
    from ngpm_runtime.inference.smc import smc

    program, origin = vines_program()
    target = disk_target()
    start = target.start_pose(program.viewport)

    def run(seed: int):
        like = ShapeLikelihood(target.mask, program.viewport)
        return smc(program, like, args.particles, seed=seed, resample=args.resample,
                   start=start, canvas_size=target.size, target_mask=target.mask)

    run(100)  # warm-up
    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        run(0)
        prof.disable()
        pstats.Stats(prof, stream=sys.stdout).sort_stats("tottime").print_stats(25)
        return
    secs, cpus, psteps, stepss, nprims, sims = [], [], [], [], [], []
    from ngpm_runtime.image.raster import rasterize
    from ngpm_runtime.inference.likelihood import similarity

    for seed in range(args.runs):
        t0, c0 = time.perf_counter(), time.process_time()
        res = run(seed)
        secs.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
        psteps.append(res.info["particle_steps"])
        stepss.append(res.steps)
        nprims.append(len(res.best.primitives))
        img = rasterize(res.best.primitives, program.viewport, *target.size)
        sims.append(similarity(img, target.mask))
    med = statistics.median(secs)
    print(f"vines ({origin}), {args.particles} particles, {args.resample} resampling, "
          f"50x50 disk target, {args.runs} runs, one core")
    print(f"seconds per run: median {med:.3f} (min {min(secs):.3f}, max {max(secs):.3f}); "
          f"CPU seconds median {statistics.median(cpus):.3f}")
    print(f"particle-steps per run: median {statistics.median(psteps):.0f}; "
          f"SMC steps median {statistics.median(stepss):.0f}")
    print(f"particle-steps per second: {sum(psteps) / sum(secs):,.0f}")
    print(f"best particle: median {statistics.median(nprims):.0f} primitives, "
          f"similarity median {statistics.median(sims):.3f}")
    if origin != "compiled":
        return
    targets = glyph_targets(args.targets)
    guided(program, targets, args.guide)
    trace_jobs(program, targets[:6])


def glyph_targets(count: int) -> list:
    import tempfile

    from ngpm_runtime.image.targets import load_dataset

    from ngpm_compiler.datasets.build import build_dataset

    with tempfile.TemporaryDirectory() as tmp:
        build_dataset("glyphs", tmp, count=count, seed=0)
        return load_dataset(tmp)


class CountingProposal:
    """Counts the proposal calls of the proposal it wraps."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.uses_features = inner.uses_features
        self.calls = 0

    def propose(self, site, args, features, rng):
        self.calls += 1
        return self.inner.propose(site, args, features, rng)


def guided(program, targets: list, guide_path: str) -> None:
    """Guided N=10 on each target (best of 3 runs each): seconds and calls per result."""
    from ngpm_runtime.image.raster import rasterize
    from ngpm_runtime.inference.guide import Guide
    from ngpm_runtime.inference.likelihood import ShapeLikelihood, similarity
    from ngpm_runtime.inference.smc import smc

    if not Path(guide_path).is_file():
        print(f"no guide at {guide_path}: no guided figures")
        return
    vp = program.viewport
    prop = CountingProposal(Guide.load(guide_path, program))
    for label, proposal, n in (("guided N=10", prop, 10), ("unguided N=10", None, 10),
                               ("unguided N=200", None, 200)):
        secs, cpus, sims = [], [], []
        prop.calls = 0
        for t in targets:
            best_wall, best_cpu = math.inf, math.inf
            for _ in range(3):
                t0, c0 = time.perf_counter(), time.process_time()
                res = smc(program, ShapeLikelihood(t.mask, vp), n, proposal=proposal, seed=0,
                          start=t.start_pose(vp), canvas_size=t.size, target_mask=t.mask)
                best_wall = min(best_wall, time.perf_counter() - t0)
                best_cpu = min(best_cpu, time.process_time() - c0)
            secs.append(best_wall)
            cpus.append(best_cpu)
            sims.append(similarity(rasterize(res.best.primitives, vp, *t.size), t.mask))
        calls = (f", {prop.calls / (3 * len(targets)):.0f} proposal calls per result"
                 if proposal is prop else "")
        print(f"{label}: {statistics.mean(secs):.4f} s per result (CPU "
              f"{statistics.mean(cpus):.4f}; best of 3, mean over {len(targets)} glyphs)"
              f"{calls}; similarity mean {statistics.mean(sims):.3f}")


def trace_jobs(program, targets: list) -> None:
    """The 600-particle trace job (traces.run_job) and the same run with features for
    every particle (record_trace=True), CPU seconds per job."""
    from ngpm_runtime.inference.likelihood import ShapeLikelihood
    from ngpm_runtime.inference.smc import smc

    from ngpm_compiler.learning.traces import run_job

    vp = program.viewport
    job, full = [], []
    for t in targets:
        c0 = time.process_time()
        run_job(program, t, 5, 600)
        c1 = time.process_time()
        smc(program, ShapeLikelihood(t.mask, vp), 600, seed=5, record_trace=True,
            start=t.start_pose(vp), canvas_size=t.size, target_mask=t.mask)
        c2 = time.process_time()
        job.append(c1 - c0)
        full.append(c2 - c1)
    print(f"trace job, 600 particles: {statistics.mean(job):.3f} CPU s per job (values "
          f"recorded, best replayed) vs {statistics.mean(full):.3f} with features for every "
          f"particle; mean over {len(targets)} glyphs")


if __name__ == "__main__":
    main()
