"""Circuits: guided SMC (N = 10, the bundled circuit guide) against unguided SMC at a ladder of
N under the circuit likelihood (the paper's equation 2), one core, runs interleaved.

Every run grows the bundled vines into the blank 50 x 50 canvas from the bottom middle
(`grow.circuit_target`, as `ngpmc grow --likelihood circuit` does); its score is equation 2's
argument, edge(I) * (1 - |fill(I) - 0.5| / 0.5) of the best particle (1 is the optimum). Per
repeat (seed `evaluation.runs.run_seed(0, repeat, N, 0)`), each guided N and then every N of
the ladder run in turn, so a load change touches all alike. Printed: mean score (95% interval over
repeats) and mean CPU seconds per configuration, the unguided N that matches the guided score
(log-interpolated, evaluation.runs.n_to_match) and the equal-score time ratio: the unguided
CPU time to reach the guided score (evaluation.runs.time_to_reach) over guided SMC's.

Usage: python benchmarks/circuit.py [--guide PATH] [--previous PATH] [--repeats 20]
       [--guided-n 10[,5,...]] [--ladder 10,20,50,100,200,400,600,1000]
       [--md docs/results/circuit_guide.md]
--previous adds a second guide (rows "previous") at the same guided N and seeds, run right
after the first in every repeat: a new guide against the one it replaces, in one run.
CPU seconds, not wall: the machine may be shared. --md also writes what it prints, with the
load average, as Markdown (docs/results/circuit_guide.md, which scripts/headline.py copies
into docs/results/README.md).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core

ROOT = Path(__file__).resolve().parents[1]
LADDER = "10,20,50,100,200,400,600,1000"


def one_run(program: Any, guide: Any, n: int, seed: int) -> tuple[float, float, int]:
    """(circuit score of the best particle, CPU seconds, primitives) of one run."""
    from ngpm_runtime.grow import grow

    c0 = time.process_time()
    res = grow(program, None, guide, n, seed, "circuit")
    return res.similarity, time.process_time() - c0, len(res.primitives)


def main() -> int:
    sys.path[:0] = [str(ROOT), str(ROOT / "runtime")]
    from ngpm_runtime import bundled
    from ngpm_runtime.inference.guide import Guide

    from ngpm_compiler.evaluation.runs import (
        curve,
        match_text,
        n_to_match,
        run_seed,
        summarize,
        t_interval,
        time_to_reach,
    )

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--guide", help="circuit guide .onnx (default: the bundled one)")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--previous", help="a second guide .onnx run beside it (rows 'previous')")
    ap.add_argument("--guided-n", default="10", help="guided N, comma-separated (default 10)")
    ap.add_argument("--ladder", default=LADDER)
    ap.add_argument("--md", help="also write the table and the ratio to this Markdown file")
    args = ap.parse_args()
    program = bundled.bundled_program()
    guide = (
        Guide.load(args.guide, program) if args.guide else bundled.bundled_guide(program, "circuit")
    )
    ladder = [int(x) for x in args.ladder.split(",")]
    guided_ns = [int(x) for x in args.guided_n.split(",")]
    models: list[tuple[str, Any, list[int]]] = [("guided", guide, guided_ns)]
    if args.previous:
        models.append(("previous", Guide.load(args.previous, program), guided_ns))
    models.append(("unguided", None, ladder))
    one_run(program, guide, 2, 0)  # kernels loaded (or compiled) before timing
    one_run(program, None, 2, 0)
    rows = []
    for rep in range(args.repeats):
        for model, proposal, ns in models:
            for n in ns:
                score, cpu, prims = one_run(program, proposal, n, run_seed(0, rep, n, 0))
                rows.append(
                    {
                        "model": model,
                        "n": n,
                        "dataset": "circuit",
                        "target": f"circuit_{rep:02d}",
                        "similarity": score,
                        "seconds": cpu,
                        "primitives": prims,
                    }
                )
    prev = f" (previous: `{args.previous}`)" if args.previous else ""
    lines = [
        f"Guide: `{Path(guide.path).name}`{prev}. {args.repeats} repeats (seeds); mean score "
        "(equation 2's argument) with its 95% interval over repeats, mean CPU seconds and "
        "primitives per run.",
        "",
        "| run | N | score | 95% CI | CPU s | primitives |",
        "|---|---|---|---|---|---|",
    ]
    for model, _, ns in models:
        for n in ns:
            sub = [r for r in rows if r["model"] == model and r["n"] == n]
            m, lo, hi = t_interval([r["similarity"] for r in sub])
            secs = sum(r["seconds"] for r in sub) / len(sub)
            prims = sum(r["primitives"] for r in sub) / len(sub)
            lines.append(
                f"| {model} | {n} | {m:.3f} | [{lo:.3f}, {hi:.3f}] | {secs:.3f} | {prims:.0f} |"
            )
    summary = summarize(rows, "circuit")
    ns, scores, secs = curve(summary, "unguided")
    lines.append("")
    for g in (r for r in summary if r["model"] != "unguided"):
        cross = n_to_match(summary, g["mean_similarity"])
        t_u = time_to_reach(scores, secs, g["mean_similarity"])
        where, ratio = match_text(cross, t_u, g["mean_seconds"], ns, secs)
        lines.append(
            f"{g['model'].capitalize()} N = {g['n']} scores {g['mean_similarity']:.3f} in "
            f"{g['mean_seconds']:.3f} s; unguided SMC matches it at {where}: **{ratio}** "
            "faster at equal score."
        )
    lines.append(f"(Load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores at the end.)")
    print("\n".join(lines))
    if args.md:
        from ngpm_runtime.files import atomic_write

        atomic_write(args.md, "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
