"""3D grow cost of two runtime versions, run in turn, and whether their seeded runs agree.

    python benchmarks/compare3d.py OLD_RUNTIME_DIR [--rounds 4] [--targets DIR] [--k 4]
    python benchmarks/compare3d.py --profile [--targets DIR] [--k 4]

OLD_RUNTIME_DIR holds an older `ngpm_runtime` package (for example `git worktree add
/tmp/old <commit>`, then /tmp/old/runtime). Each round runs, as fresh processes, this file's
`--child` with the old runtime and with this checkout's, one after the other (alternating
which goes first). A child grows the bundled vines3d into the first `--k` targets of the
held-out `revolved` set (built in work/revolved when missing, as benchmarks/eval3d.py does),
seeds 0 and 1: guided N = 10 with the bundled guide, unguided N = 100, on one core. It prints
the CPU seconds per run and a hash of every run's trees, similarity, weights and evidence:
equal hashes mean the versions' seeded runs are the same bit for bit. The table gives the
median over rounds and the load average. `--profile` runs the same grows with this
checkout's runtime under cProfile and prints the share of each part of a run (the time
inside the named functions, callees included; the turtle's: its own functions' time).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
MODES = (("guided N=10", True, 10), ("unguided N=100", False, 100))
PARTS = {  # part -> (file, function) whose cumulative time it is
    "site rounds": ("inference/smc.py", "_serve"),
    "  3D feature rows": ("volume/features.py", "rows_from"),
    "  guide networks, draws": ("inference/guide.py", "propose_rows"),
    "derivation": ("geometry/derive.py", "advance_all"),
    "resampling": ("inference/smc.py", "_resample"),
    "drawing voxels": ("volume/raster.py", "draw"),
    "likelihood increments": ("volume/likelihood.py", "increment"),
}


def child(targets_dir: str, k: int) -> None:
    """One process's runs: JSON {mode: [CPU s per run, hash]} on stdout."""
    from ngpm_runtime.grow import grow

    program, guide, targets = _grows(targets_dir, k)
    grow(program, targets[0], guide, 10, 0)  # kernels loaded, caches warm
    out = {}
    for label, guided, n in MODES:
        digest = hashlib.sha256()
        t0 = time.process_time()
        runs = 0
        for seed in (0, 1):
            for t in targets:
                r = grow(program, t, guide if guided else None, n, seed)
                runs += 1
                run = (r.primitives, r.similarity, r.smc.log_weights.tolist(), r.smc.log_evidence)
                digest.update(repr(run).encode())
        out[label] = [(time.process_time() - t0) / runs, digest.hexdigest()[:16]]
    print(json.dumps(out))


def _grows(targets_dir: str, k: int) -> tuple[Any, Any, list[Any]]:
    from ngpm_runtime import bundled
    from ngpm_runtime.volume.load import load_volume_dataset

    program = bundled.bundled_program3d()
    guide = bundled.bundled_guide3d(program)
    return program, guide, load_volume_dataset(targets_dir, program)[:k]


def profile(targets_dir: str, k: int) -> None:
    """The share of each part of a 3D run (PARTS, and the 3D turtle), guided and unguided."""
    import cProfile
    import pstats

    from ngpm_runtime.grow import grow

    program, guide, targets = _grows(targets_dir, k)
    grow(program, targets[0], guide, 10, 0)
    print(f"share of a grow's time under cProfile, {k} revolved targets x 2 seeds")
    for label, guided, n in MODES:
        prof = cProfile.Profile()
        prof.enable()
        for seed in (0, 1):
            for t in targets:
                grow(program, t, guide if guided else None, n, seed)
        prof.disable()
        stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
        cum = {
            (Path(f).parent.name + "/" + Path(f).name, fn): v[3] for (f, _, fn), v in stats.items()
        }
        total = cum[("ngpm_runtime/grow.py", "grow")]
        turtle = sum(v[2] for (f, _, _), v in stats.items() if f.endswith("turtle3d.py"))
        print(f"{label}: {total:.2f} s in all")
        for part, key in PARTS.items():
            print(f"  {part:26s} {100 * cum.get(key, 0.0) / total:5.1f}%")
        print(f"  {'3D turtle (own time)':26s} {100 * turtle / total:5.1f}%")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", nargs="?", help="directory holding the older ngpm_runtime package")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--targets", default=str(ROOT / "work" / "revolved"))
    ap.add_argument("--k", type=int, default=4)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--profile", action="store_true", help="where this runtime's time goes")
    args = ap.parse_args()
    if args.child:
        child(args.targets, args.k)
        return
    if args.profile:
        profile(args.targets, args.k)
        return
    if args.old is None:
        ap.error("give OLD_RUNTIME_DIR")
    if not (Path(args.targets) / "index.json").is_file():
        from ngpm_compiler.cli import main as ngpmc

        ngpmc(["targets", "build", "revolved", "-o", args.targets])
    env0 = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    paths = {"before": str(Path(args.old).resolve()), "after": str(ROOT / "runtime")}
    runs: dict[str, dict[str, list]] = {"before": {}, "after": {}}
    load0 = os.getloadavg()[0]
    for r in range(args.rounds):
        for which in ("before", "after") if r % 2 == 0 else ("after", "before"):
            env = dict(env0, PYTHONPATH=os.pathsep.join([paths[which], str(ROOT)]))
            cmd = [sys.executable, __file__, "--child", "--targets", args.targets]
            proc = subprocess.run(
                [*cmd, "--k", str(args.k)], env=env, check=True, capture_output=True, text=True
            )
            for label, got in json.loads(proc.stdout.splitlines()[-1]).items():
                runs[which].setdefault(label, []).append(got)
    print(
        f"CPU s per grow run, median of {args.rounds} rounds (before and after in turn), "
        f"{args.k} revolved targets x 2 seeds; load average {load0:.1f} at the start, "
        f"{os.getloadavg()[0]:.1f} at the end"
    )
    print(f"{'':16s} {'before':>8s} {'after':>8s}  after/before  same runs")
    for label, _, _ in MODES:
        b, a = runs["before"][label], runs["after"][label]
        tb = statistics.median(x[0] for x in b)
        ta = statistics.median(x[0] for x in a)
        same = len({x[1] for x in b + a}) == 1
        print(f"{label:16s} {tb:8.3f} {ta:8.3f}  {ta / tb:12.2f}  {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()
