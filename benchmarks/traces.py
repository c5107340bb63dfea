"""Trace recording throughput: the local process pool vs Ray (a local instance) on this machine.

    python3 benchmarks/traces.py [--traces 40] [--particles 200] [--workers 2]
                                 [--ray-address ADDRESS]

Records the same vines traces (scribble targets, made on the fly) with `--backend local` and
`--backend ray`, `--workers` processes / Ray CPUs each, into fresh directories, and prints per
backend: the wall time of the whole call (starting the workers or Ray included), the time to
the first finished job, traces per second overall and after the first job (the steady rate),
and whether the shards are byte-identical. Needs `pip install ray` for the Ray row (or
`--ray-address` to measure a cluster; then the figures are the cluster's). The machine may be
shared: figures can be inflated.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import Any

from ngpm_compiler.datasets.build import build_dataset
from ngpm_compiler.learning.trace_store import TraceStore
from ngpm_compiler.learning.traces import TraceConfig, generate_traces

ROOT = Path(__file__).resolve().parents[1]


def run(cfg: TraceConfig, out: Path) -> dict[str, Any]:
    stamps: list[float] = []
    t0 = time.perf_counter()
    m = generate_traces(
        cfg, out, progress=False, on_job=lambda _job: stamps.append(time.perf_counter())
    )
    wall = time.perf_counter() - t0
    first = stamps[0] - t0 if stamps else wall
    steady = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if len(stamps) > 1 else 0.0
    return {
        "wall": wall,
        "first": first,
        "jobs": m["jobs_done"],
        "kept": m["kept"],
        "rate": m["kept"] / wall,
        "steady": steady * m["kept"] / max(1, m["jobs_done"]),
        "shards": {p.name: p.read_bytes() for p in TraceStore(out).shard_paths()},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--traces", type=int, default=40)
    ap.add_argument("--particles", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--ray-address", default=None)
    ap.add_argument("--backends", default="local,ray")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "scribbles"
        build_dataset("scribbles", data, count=20, seed=0, mirror=True)
        print(
            f"vines, {args.traces} traces kept, {args.particles} particles, "
            f"{args.workers} workers / Ray CPUs"
        )
        results = {}
        for backend in args.backends.split(","):
            cfg = TraceConfig(
                grammar=str(ROOT / "grammars" / "vines.lsys"),
                targets=str(data),
                n=args.traces,
                particles=args.particles,
                workers=args.workers,
                backend=backend,
                shard_size=10,
                ray_address=args.ray_address if backend == "ray" else None,
            )
            r = results[backend] = run(cfg, Path(tmp) / backend)
            print(
                f"{backend:>5}: {r['wall']:6.1f} s wall ({r['jobs']} jobs), first job after "
                f"{r['first']:.1f} s, {r['rate']:.2f} traces/s overall, "
                f"{r['steady']:.2f} traces/s after the first job",
                flush=True,
            )
        if len(results) > 1:
            same = len({repr(sorted(r["shards"].items())) for r in results.values()}) == 1
            print(f"shards byte-identical across backends: {same}")


if __name__ == "__main__":
    main()
