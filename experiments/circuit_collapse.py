"""Circuits at N = 10: do low runs come from a population collapsed onto a particle that
finished early, and does keeping finished particles out of resampling help? (Issue #23; the
answer and the figures: experiments/notes/circuit_guide_retrain.md, "Collapse onto an
early-finished particle".)

Usage: python experiments/circuit_collapse.py {base,aside,archive} [REPEATS]

Every mode runs the bundled circuit guide at N = 10 on the Python deriver (the compiled one
gives the same runs; the variants patch the Python one), seeds as benchmarks/circuit.py's:
- base: SMC as shipped;
- aside: finished particles keep their slot and weight, only the live ones resample among
  themselves (their total weight kept); the roulette of live particles is off (with a heavy
  finished particle every live one falls under its threshold);
- archive: finished particles leave for an archive at each resampling and the live ones fill
  all N slots; the best particle is chosen from the final particles and the archive.
Both variants keep the weights proper (a subset resampled with its total weight kept).
Prints the mean score, runs below 0.55, mean primitives and CPU seconds per run.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "runtime")]

from ngpm_runtime import bundled  # noqa: E402
from ngpm_runtime.geometry.cons import cons_to_list  # noqa: E402
from ngpm_runtime.grow import grow  # noqa: E402
from ngpm_runtime.inference import run as runmod  # noqa: E402
from ngpm_runtime.inference import smc as smcmod  # noqa: E402
from ngpm_runtime.inference.resample import resample as draw_ancestors  # noqa: E402

from ngpm_compiler.evaluation.runs import run_seed  # noqa: E402

_resample = runmod._Run._resample
_result = runmod._Run.result


def aside(self: Any, lse: float) -> None:
    pop, n = self.pop, self.n
    live = np.asarray(pop.live, dtype=np.intp)
    if len(live) in (0, n):
        return _resample(self, lse)
    lw = pop.log_w[live]
    anc = np.arange(n)
    anc[live] = live[draw_ancestors(self.resample, lw, self.rng)]
    new_w = pop.log_w.copy()
    new_w[live] = runmod._logsumexp(lw) - math.log(len(live))
    self.log_z += lse - math.log(n)
    pop.take(anc)
    pop.log_w = new_w - (lse - math.log(n))
    self.n_resample += 1
    return None


def archive(self: Any, lse: float) -> None:
    pop, n = self.pop, self.n
    live = np.asarray(pop.live, dtype=np.intp)
    if len(live) in (0, n):
        return _resample(self, lse)
    kept = self.__dict__.setdefault("archive", [])
    for i, p in enumerate(pop.parts):
        if p.status != "live" and np.isfinite(pop.log_w[i]):
            kept.append((float(pop.log_prior[i] + pop.log_lik[i]), cons_to_list(p.prims)))
    anc = live[draw_ancestors(self.resample, pop.log_w[live], self.rng, n)]
    self.log_z += lse - math.log(n)
    pop.take(anc)
    self.n_resample += 1
    return None


def archive_result(self: Any, seconds: float) -> Any:
    res = _result(self, seconds)
    kept = self.__dict__.get("archive", [])
    score = res.best.log_prior + res.best.log_likelihood
    if kept and max(kept)[0] > score:
        prims = max(kept, key=lambda x: x[0])[1]
        res = dataclasses.replace(res, best=dataclasses.replace(res.best, primitives=prims))
    return res


def main() -> int:
    mode = sys.argv[1] if len(sys.argv) > 1 else "base"
    repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 80
    smcmod._compiled_deriver = lambda *a, **k: None  # type: ignore[assignment]
    if mode == "aside":
        runmod._Run._resample = aside  # type: ignore[method-assign]
        runmod.Population.roulette = lambda *a, **k: False  # type: ignore[method-assign]
    elif mode == "archive":
        runmod._Run._resample = archive  # type: ignore[method-assign]
        runmod._Run.result = archive_result  # type: ignore[method-assign]
    elif mode != "base":
        raise SystemExit(f"unknown mode {mode!r}: base, aside or archive")
    program = bundled.bundled_program()
    guide = bundled.bundled_guide(program, "circuit")
    scores, prims = [], []
    c0 = time.process_time()
    for rep in range(repeats):
        res = grow(program, None, guide, 10, run_seed(0, rep, 10, 0), "circuit")
        scores.append(res.similarity)
        prims.append(len(res.primitives))
    cpu = (time.process_time() - c0) / repeats
    low = sum(s < 0.55 for s in scores)
    print(
        f"{mode}: mean score {np.mean(scores):.3f}, {low} of {repeats} runs below 0.55, "
        f"{np.mean(prims):.0f} primitives, {cpu:.3f} CPU s per run"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
