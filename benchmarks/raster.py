"""Per-call CPU times of the pixel runtime for 600 vines-like particles on a 50 x 50 canvas.

Run: python benchmarks/raster.py [n_particles]
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np
from ngpm_runtime.image.features import FeatureMaker
from ngpm_runtime.image.raster import Canvas
from ngpm_runtime.inference.likelihood import CircuitLikelihood, ShapeLikelihood
from ngpm_runtime.program import Program, Site

VP = (-12.0, 12.0, -22.0, 2.0)


def _prims(rng: np.random.Generator, n: int, kinds: tuple[str, ...]) -> list[tuple]:
    out = []
    for _ in range(n):
        x, y = rng.uniform(-10, 10), rng.uniform(-20, 0)
        a = rng.uniform(0, 360)
        kind = kinds[rng.integers(len(kinds))]
        if kind == "seg":
            out.append(
                (
                    "seg",
                    x,
                    y,
                    x + 2 * math.cos(math.radians(a)),
                    y + 2 * math.sin(math.radians(a)),
                    rng.uniform(0.1, 0.75),
                )
            )
        elif kind == "leaf":
            out.append(("leaf", x, y, a, 2.05, 0.975))
        else:
            out.append(("disk", x, y, 0.75))
    return out


def _time(fn, reps: int) -> float:
    """Best CPU milliseconds per call over 5 rounds of `reps` calls (robust to a busy host)."""
    best = math.inf
    for _ in range(5):
        t0 = time.process_time()
        for _ in range(reps):
            fn()
        best = min(best, (time.process_time() - t0) / reps * 1e3)
    return best


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 600
    rng = np.random.default_rng(0)
    idx = np.arange(n)
    yy, xx = np.mgrid[0:50, 0:50]
    target = (np.abs(xx - 25) < 6) & (yy > 5)
    reps = 50
    batches = {
        k: [_prims(rng, n, k) for _ in range(reps)] for k in [("seg",), ("seg", "leaf", "disk")]
    }
    for kinds, sets in batches.items():
        canvas = Canvas(n, 50, 50, VP)
        it = iter(sets * 5)
        ms = _time(lambda it=it, canvas=canvas: canvas.draw(idx, next(it)), reps)
        print(f"Canvas.draw  {n} particles {'+'.join(kinds):15s} {ms:7.3f} ms/call")
    canvas = Canvas(n, 50, 50, VP)
    draws = [canvas.draw(idx, p) for p in batches[("seg",)][:reps]]
    for name, lik in (
        ("ShapeLikelihood", ShapeLikelihood(target, VP)),
        ("CircuitLikelihood", CircuitLikelihood(VP)),
    ):
        state = lik.start(n)
        it = iter(draws * 5)
        ms = _time(lambda it=it, lik=lik, state=state: lik.increment(state, canvas, next(it)), reps)
        print(f"{name}.increment {n} particles        {ms:7.3f} ms/call")
    anc = np.sort(rng.integers(0, n, n))
    ms = _time(lambda: canvas.take(anc), reps)
    print(f"Canvas.take  {n} particles                 {ms:7.3f} ms/call")
    site = Site(index=0, id="B/0/normal0", kind="normal", arity=1)
    prog = Program(
        name="b", sites=[site], axiom=lambda ctx: [], productions={}, derivation_length=400
    )
    fm = FeatureMaker(prog, VP, target)
    turtle = np.stack(
        [rng.uniform(-12, 12, n), rng.uniform(-22, 2, n), rng.uniform(0, 360, n), np.full(n, 0.5)],
        axis=1,
    )
    depth, params, args = np.ones(n), np.ones((n, 1)), np.ones((n, 2))
    ms = _time(lambda: fm.features(site, canvas, idx, turtle, depth, params, args), reps)
    print(f"FeatureMaker.features {n} particles        {ms:7.3f} ms/call")


if __name__ == "__main__":
    main()
