"""Unguided SMC on vines against a 50x50 filled-disk target: seconds per run and
particle-steps per second (one core). Usage: python benchmarks/smc.py [--profile]

Uses the compiler's output for grammars/vines.lsys when the compiler is importable, else the
hand-written fixture tests/fixtures/vines_sampler.py.
"""

from __future__ import annotations

import argparse
import cProfile
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
        from ngpm_compiler.compile import compile_grammar
    except ImportError:
        return load_program(ROOT / "tests" / "fixtures" / "vines_sampler.py"), "fixture"
    return compile_grammar(str(ROOT / "grammars" / "vines.lsys")).program(), "compiled"


def disk_target(size: int = 50):
    """A filled disk in the upper middle of the image; start at its bottom, heading up."""
    from ngpm_runtime.targets import Target

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
    args = ap.parse_args()

    from ngpm_runtime.likelihood import ShapeLikelihood
    from ngpm_runtime.smc import smc

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
    from ngpm_runtime.likelihood import similarity
    from ngpm_runtime.raster import rasterize

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


if __name__ == "__main__":
    main()
