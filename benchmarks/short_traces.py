"""What dropping short traces costs: the share of trace jobs whose best particle drew fewer
than 10 primitives (the paper's code dropped them; `ngpmc learn`, `traces` and `iterate`
keep them as data unless `--min-primitives 10` asks), and the share of the trace time they
took.

    python3 benchmarks/short_traces.py [--traces 40] [--particles 600] [--grammar G]

Records `--traces` unguided traces per target set (scribbles and `varied`, 15 of each plus
mirrored copies, made on the fly) keeping every trace (min_primitives 1), with one worker so
that the jobs' seconds follow their ids, and prints per set and in all: jobs, short jobs,
their seconds, and the time per kept trace when they are dropped and when they are kept.
The machine may be shared: compare the shares, not the seconds.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from ngpm_compiler.datasets.build import build_dataset
from ngpm_compiler.learning.trace_store import TraceStore
from ngpm_compiler.learning.traces import TraceConfig, generate_traces

ROOT = Path(__file__).resolve().parents[1]
SHORT = 10  # the paper's threshold


def measure(grammar: str, targets: Path, out: Path, n: int, particles: int) -> dict[str, float]:
    cfg = TraceConfig(
        grammar=grammar,
        targets=str(targets),
        n=n,
        particles=particles,
        workers=1,
        min_primitives=1,
        seed=3,
    )
    m = generate_traces(cfg, out, progress=False)
    shards = [np.load(p) for p in TraceStore(out).shard_paths()]
    jobs = np.concatenate([a["jobs"] for a in shards])
    prims = np.concatenate([a["n_prims"] for a in shards])[np.argsort(jobs)]
    secs = np.array(m["job_seconds"])
    short = (prims >= 0) & (prims < SHORT)
    return {
        "jobs": len(prims),
        "short": int(short.sum()),
        "short_seconds": float(secs[short].sum()),
        "seconds": float(secs.sum()),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--traces", type=int, default=40, help="traces per target set (40)")
    ap.add_argument("--particles", type=int, default=600, help="SMC particles (600)")
    ap.add_argument("--grammar", default=str(ROOT / "grammars" / "vines.lsys"))
    args = ap.parse_args()
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("scribbles", "varied"):
            build_dataset(name, Path(tmp) / name, count=15, mirror=True)
            rows[name] = measure(
                args.grammar,
                Path(tmp) / name,
                Path(tmp) / f"tr_{name}",
                args.traces,
                args.particles,
            )
    rows["all"] = {k: sum(r[k] for r in rows.values()) for k in rows["scribbles"]}
    print(
        "| set | jobs | short (< 10 primitives) | their share of the time | s per kept trace, "
        "dropped | kept |"
    )
    print("|---|---|---|---|---|---|")
    for name, r in rows.items():
        dropped = r["seconds"] / max(1, r["jobs"] - r["short"])
        kept = r["seconds"] / max(1, r["jobs"])
        print(
            f"| {name} | {r['jobs']} | {r['short']} ({100 * r['short'] / r['jobs']:.0f}%) | "
            f"{100 * r['short_seconds'] / r['seconds']:.1f}% | {dropped:.2f} | {kept:.2f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
