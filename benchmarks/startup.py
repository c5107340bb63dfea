"""Whole-process times of `ngpmc`: `--help`, and `ngpmc grow` (bundled guide, N=10) with
the kernels' disk cache warm and cold.

    python benchmarks/startup.py [--old OLD_CHECKOUT] [--rounds 5]

Each round runs, as fresh processes: `ngpmc --help`, a warm `ngpmc grow` of the demo horse
(the kernels compiled and cached before the first round), and, when --old is given, the
same two with OLD_CHECKOUT's `ngpm_compiler` and `ngpm_runtime` on PYTHONPATH, the versions
in turn (alternating which goes first). Then one cold run: `ngpmc grow` with an empty
NUMBA_CACHE_DIR (every kernel compiled in that process). Printed: median wall and CPU
seconds (user + sys of the child) per command and version. Run from any folder: the
processes start in a temporary folder, so the checkout's files on the path are the ones
PYTHONPATH names.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HORSE = "runtime/ngpm_runtime/data/demo_horse.png"


def _env(checkout: Path, cache: str | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(checkout), str(checkout / "runtime")])
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = cache
    return env


def timed(args: list[str], env: dict[str, str], cwd: str) -> tuple[float, float]:
    """(wall, CPU) seconds of one child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "ngpm_compiler.cli", *args],
        env=env,
        cwd=cwd,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def commands(checkout: Path, out: str) -> dict[str, list[str]]:
    return {
        "ngpmc --help": ["--help"],
        "ngpmc grow (warm)": ["grow", str(checkout / HORSE), "-N", "10", "-o", out],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--old", default=None, help="an older checkout to compare with")
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    versions = {"this": ROOT}
    if args.old:
        versions["old"] = Path(args.old).resolve()
    times: dict[tuple[str, str], list[tuple[float, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "vine.png")
        for checkout in versions.values():  # fill the caches before timing
            timed(commands(checkout, out)["ngpmc grow (warm)"], _env(checkout), tmp)
        order = list(versions)
        for r in range(args.rounds):
            for name in order if r % 2 == 0 else order[::-1]:
                checkout = versions[name]
                for label, cmd in commands(checkout, out).items():
                    times.setdefault((label, name), []).append(timed(cmd, _env(checkout), tmp))
        cold_cache = str(Path(tmp) / "numba-cold")
        cmd = commands(ROOT, out)["ngpmc grow (warm)"]
        times[("ngpmc grow (cold: empty kernel cache)", "this")] = [
            timed(cmd, _env(ROOT, cold_cache), tmp)
        ]
    print(f"whole-process seconds, median of {args.rounds} rounds (load {os.getloadavg()[0]:.1f})")
    print(f"{'':40s} {'version':>8s} {'wall':>7s} {'CPU':>7s}")
    for (label, name), rs in times.items():
        wall = statistics.median(w for w, _ in rs)
        cpu = statistics.median(c for _, c in rs)
        print(f"{label:40s} {name:>8s} {wall:7.2f} {cpu:7.2f}")


if __name__ == "__main__":
    main()
