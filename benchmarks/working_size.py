"""Guided vs unguided SMC at larger working sizes (`ngpmc grow --size`), bundled guide.

The bundled guide was trained at 50 x 50. `grow` suggests a larger `--size` when a picture's
thin strokes vanish at 50; this prints whether guided N=10 still beats unguided SMC there:
per size, the mean over targets of the median similarity (over seeds) and the mean seconds
per run, for guided N=10 and unguided N=10 and N=100, on glyphs and silhouettes spread over
their sets (as benchmarks/smc.py picks them), runs interleaved.

Usage: python benchmarks/working_size.py [--sizes 50,100,128] [--glyphs 6] [--silhouettes 6]
       [--seeds 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

CONFIGS = (("guided", 10), ("unguided", 10), ("unguided", 100))


def targets_at(sizes: list[int], n_glyphs: int, n_silhouettes: int) -> dict[int, list[Any]]:
    """The same picked targets loaded at each working size."""
    from ngpm_runtime.image.targets import load_dataset

    from ngpm_compiler.datasets.build import build_dataset
    from ngpm_compiler.experiments.shape import pick

    out: dict[int, list[Any]] = {s: [] for s in sizes}
    with tempfile.TemporaryDirectory() as tmp:
        for name, k in (("glyphs", n_glyphs), ("silhouettes", n_silhouettes)):
            d = Path(tmp) / name
            build_dataset(name, d, count=None, seed=0)
            names = {
                t.name
                for t in pick([t for t in load_dataset(d, size=50) if not t.name.endswith("_m")], k)
            }
            for s in sizes:
                out[s] += [t for t in load_dataset(d, size=s) if t.name in names]
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="50,100,128")
    ap.add_argument("--glyphs", type=int, default=6)
    ap.add_argument("--silhouettes", type=int, default=6)
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    from ngpm_runtime import bundled
    from ngpm_runtime.grow import grow

    program = bundled.bundled_program()
    guide = bundled.bundled_guide(program)
    sizes = [int(s) for s in args.sizes.split(",")]
    by_size = targets_at(sizes, args.glyphs, args.silhouettes)
    sims: dict[tuple[int, str, int], list[float]] = {}
    secs: dict[tuple[int, str, int], list[float]] = {}
    for size in sizes:
        for target in by_size[size]:
            for kind, n in CONFIGS:
                runs = []
                for seed in range(args.seeds):
                    t0 = time.process_time()
                    res = grow(program, target, guide if kind == "guided" else None, n, seed)
                    secs.setdefault((size, kind, n), []).append(time.process_time() - t0)
                    runs.append(res.similarity)
                sims.setdefault((size, kind, n), []).append(statistics.median(runs))
    head = " | ".join(f"{k} N={n}" for k, n in CONFIGS)
    print(f"{len(by_size[sizes[0]])} targets x {args.seeds} seeds; similarity (CPU s per run)")
    print(f"| size | {head} |")
    print("|---" * (len(CONFIGS) + 1) + "|")
    for size in sizes:
        cells = [
            f"{statistics.mean(sims[size, k, n]):.3f} ({statistics.mean(secs[size, k, n]):.2f})"
            for k, n in CONFIGS
        ]
        print(f"| {size} x {size} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
