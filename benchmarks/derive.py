"""The deriver's cost per SMC step: time inside `Deriver.advance_all` (the per-particle Python
derivation: productions, memo tables, turtle), apart from the numeric kernels.

    python benchmarks/derive.py [--seeds 4] [--json PATH]
    python benchmarks/derive.py --compare OLD_RUNTIME_DIR [--rounds 3] [--seeds 4]

Runs on the bundled vines program, one core, each case in turn per seed:
- guided N=10: `grow` with the bundled guide into the four demo targets (`ngpmc grow
  runtime/ngpm_runtime/data/demo_horse.png -N 10` and the three others);
- unguided N=600: `grow` without a guide into the same targets;
- traces: a trace job's SMC (600 particles, values recorded, unguided; `ngpmc traces`).
Printed per case: CPU microseconds in the deriver per SMC step and per particle-step,
particle advances per step and the deriver's share of the run's CPU time. The deriver's time is
measured by making a run's recorded `advance_all` calls again back to back (`measure`): CPU time,
so a shared machine's load changes it little. "in run": wall microseconds inside it
per step during the run itself (a timer around each call, counted in): what a run pays,
caches cold between the rounds' numeric work included, but inflated by a shared machine's
load.

--compare runs this script alternately with OLD_RUNTIME_DIR's `ngpm_runtime` (for example
`git archive <commit> runtime | tar -x -C /tmp/old`, then /tmp/old/runtime) and with this
checkout's, `--rounds` times each, and prints the medians of both and after/before: one
interleaved run, so both versions see the same machine load.

Figures (issue #22, the deriver pass): `--compare` against commit bec1549's runtime,
`--rounds 3 --seeds 1`, one interleaved run on the 2-core machine shared with other jobs
(load average 6-8); medians, microseconds per SMC step:

    case             CPU before  after  ratio   in run before  after  ratio
    guided N=10           125.2   99.3   0.79           496.4  347.8   0.70
    unguided N=600       3425.9 2864.6   0.84          7363.3 6299.8   0.86
    traces N=600         3491.3 2803.0   0.80          8124.6 6678.5   0.82

Per particle-step (CPU): guided 13.4 -> 10.7 us, unguided 6.6 -> 5.5 us. Seeded runs draw
the same values, weights and pictures as before (bit for bit).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core

HERE = Path(__file__).resolve().parent
CASES = ("guided N=10", "unguided N=600", "traces N=600")
TARGETS = ("horse", "glyph", "heart", "spiral")


def measure(seeds: int, reps: int = 3) -> dict[str, dict[str, float]]:
    """Deriver CPU seconds, SMC steps, particle-steps, particle advances and run CPU seconds
    per case, summed over the targets and seeds.

    Each run records every `advance_all` call (the deriver and copies of the particles as they were
    before the call); the recorded calls are then made again back to back, `reps` times,
    and the fastest repetition's CPU time (process_time, robust to a shared machine's load)
    is the deriver's time: the same work, in the same order, as in the run."""
    from ngpm_runtime.bundled import bundled_guide, bundled_program, demo_target_path
    from ngpm_runtime.geometry.derive import Deriver
    from ngpm_runtime.grow import grow
    from ngpm_runtime.image.targets import load_target
    from ngpm_runtime.inference.smc import TraceRecording

    program = bundled_program()
    guide = bundled_guide(program)
    targets = [load_target(demo_target_path(name)) for name in TARGETS]
    calls: list[tuple[Any, list[Any]]] = []
    # SMC advances a round's particles in one `advance_all` call (an older runtime: one
    # `advance` call per particle); that method is recorded and timed
    name = "advance_all" if hasattr(Deriver, "advance_all") else "advance"
    advance = getattr(Deriver, name)
    inside = [0.0]

    def recorded(self: Any, arg: Any) -> Any:
        parts = list(arg) if name == "advance_all" else [arg]
        calls.append((self, [p.copy() for p in parts]))
        return advance(self, parts if name == "advance_all" else arg)

    def timed(self: Any, arg: Any) -> Any:
        t = time.perf_counter()
        code = advance(self, arg)
        inside[0] += time.perf_counter() - t
        return code

    runs = {
        "guided N=10": {"guide": guide, "n": 10},
        "unguided N=600": {"guide": None, "n": 600},
        "traces N=600": {"guide": None, "n": 600, "trace": TraceRecording.VALUES},
    }
    grow(program, targets[0], guide, 10, 99)  # warm-up: imports, memo tables
    keys = ("derive", "in run", "steps", "psteps", "calls", "run")
    out = {c: dict.fromkeys(keys, 0.0) for c in runs}
    for seed in range(seeds):
        for target in targets:
            for case, kw in runs.items():
                trace = kw.get("trace", TraceRecording.NONE)
                setattr(Deriver, name, timed)
                inside[0] = 0.0
                c0 = time.process_time()
                res = grow(program, target, kw["guide"], kw["n"], seed, trace=trace)
                row = out[case]
                row["run"] += time.process_time() - c0
                row["in run"] += inside[0]
                row["steps"] += res.smc.steps
                row["psteps"] += res.smc.info["particle_steps"]
                setattr(Deriver, name, recorded)
                calls.clear()
                grow(program, target, kw["guide"], kw["n"], seed, trace=trace)
                setattr(Deriver, name, advance)
                row["calls"] += sum(len(parts) for _, parts in calls)
                row["derive"] += replay(calls, advance, name == "advance_all", reps)
    return out


def replay(calls: list[tuple[Any, list[Any]]], advance: Any, batched: bool, reps: int) -> float:
    """The fastest of `reps` back-to-back replays of the recorded calls, CPU seconds
    (`batched`: `advance_all` calls, one per recorded list; else one `advance` each)."""
    best = float("inf")
    for _ in range(reps):
        made = [(d, [p.copy() for p in parts]) for d, parts in calls]
        c0 = time.process_time()
        for d, parts in made:
            if batched:
                advance(d, parts)
            else:
                advance(d, parts[0])
        best = min(best, time.process_time() - c0)
    return best


def figures(row: dict[str, float]) -> dict[str, float]:
    return {
        "us/step": 1e6 * row["derive"] / row["steps"],
        "in run": 1e6 * row["in run"] / row["steps"],
        "us/particle-step": 1e6 * row["derive"] / row["psteps"],
        "calls/step": row["calls"] / row["steps"],
        "share": row["derive"] / row["run"],
    }


def show(out: dict[str, dict[str, float]]) -> None:
    print(
        f"{'':16s} {'us/step':>9s} {'us/particle-step':>16s} {'calls/step':>10s} "
        f"{'share':>6s} {'in run us/step':>14s}"
    )
    for case, row in out.items():
        f = figures(row)
        print(
            f"{case:16s} {f['us/step']:9.1f} {f['us/particle-step']:16.2f} "
            f"{f['calls/step']:10.1f} {f['share']:6.2f} {f['in run']:14.1f}"
        )


def compare(old: str, rounds: int, seeds: int) -> None:
    """This checkout against OLD's runtime, run in turn (alternating which goes first)."""
    got: dict[str, list[dict[str, dict[str, float]]]] = {"before": [], "after": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            for which in ("before", "after") if r % 2 == 0 else ("after", "before"):
                env = dict(os.environ)
                if which == "before":
                    rest = env.get("PYTHONPATH", "")
                    env["PYTHONPATH"] = str(Path(old).resolve()) + (
                        os.pathsep + rest if rest else ""
                    )
                path = Path(tmp) / f"{which}{r}.json"
                cmd = [sys.executable, __file__, "--seeds", str(seeds), "--json", str(path)]
                subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
                got[which].append(json.loads(path.read_text()))
    print(
        f"deriver us per SMC step, median of {rounds} rounds (before and after in turn, "
        f"{seeds} seeds x {len(TARGETS)} demo targets each); CPU: the recorded calls made "
        "again back to back; in run: wall time inside advance during the run"
    )
    print(
        f"{'':16s} {'CPU before':>10s} {'after':>7s} {'ratio':>6s}   {'in run before':>13s} "
        f"{'after':>7s} {'ratio':>6s}   us/particle-step (CPU)"
    )
    for case in CASES:
        med = {
            (w, k): statistics.median(figures(o[case])[k] for o in got[w])
            for w in got
            for k in ("us/step", "in run", "us/particle-step")
        }
        b, a = med["before", "us/step"], med["after", "us/step"]
        rb, ra = med["before", "in run"], med["after", "in run"]
        print(
            f"{case:16s} {b:10.1f} {a:7.1f} {a / b:6.2f}   {rb:13.1f} {ra:7.1f} {ra / rb:6.2f}   "
            f"{med['before', 'us/particle-step']:.2f} -> {med['after', 'us/particle-step']:.2f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--json", help="write the sums per case to this file")
    ap.add_argument("--compare", metavar="OLD_RUNTIME_DIR")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    if args.compare:
        compare(args.compare, args.rounds, args.seeds)
        return
    out = measure(args.seeds)
    if args.json:
        Path(args.json).write_text(json.dumps(out))
    show(out)


if __name__ == "__main__":
    main()
