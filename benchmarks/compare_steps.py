"""Step cost of two runtime versions, run in turn: before/after tables for the notebook.

    python benchmarks/compare_steps.py OLD_RUNTIME_DIR [--rounds 3] [--seeds 1]

OLD_RUNTIME_DIR holds an older `ngpm_runtime` package (for example `git archive <commit>
runtime | tar -x -C /tmp/old`, then /tmp/old/runtime). Each round runs benchmarks/smc.py's
step table once with the old runtime (PYTHONPATH) and once with this checkout's, one after
the other (alternating which goes first); the table pools every run of every round and
prints the median CPU ms per SMC step of each configuration for both, and guided N=10 over
unguided N=10.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("old", help="directory holding the older ngpm_runtime package")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=1)
    args = ap.parse_args()
    runs: dict[str, dict[str, list]] = {"before": {}, "after": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for which in ("before", "after") if r % 2 == 0 else ("after", "before"):
                env = dict(os.environ)
                if which == "before":
                    env["PYTHONPATH"] = str(Path(args.old).resolve())
                out = Path(tmp) / f"{which}{r}.json"
                subprocess.run(
                    [
                        sys.executable,
                        str(HERE / "smc.py"),
                        "--seeds",
                        str(args.seeds),
                        "--json",
                        str(out),
                    ],
                    env=env,
                    check=True,
                    stdout=subprocess.DEVNULL,
                )
                for label, rs in json.loads(out.read_text()).items():
                    runs[which].setdefault(label, []).extend(rs)
    print(
        f"CPU ms per SMC step, median over {args.rounds} rounds of the step table "
        "(before and after in turn)"
    )
    print(f"{'':16s} {'before':>8s} {'after':>8s}   similarity before/after")
    med = {}
    for label in runs["after"]:
        row = []
        for which in ("before", "after"):
            rs = runs[which][label]
            med[which, label] = statistics.median(1000 * x["cpu"] / x["steps"] for x in rs)
            row.append(statistics.mean(x["sim"] for x in rs))
        print(
            f"{label:16s} {med['before', label]:8.3f} {med['after', label]:8.3f}   "
            f"{row[0]:.3f} / {row[1]:.3f}"
        )
    for which in ("before", "after"):
        ratio = med[which, "guided N=10"] / med[which, "unguided N=10"]
        print(f"guided N=10 / unguided N=10, {which}: {ratio:.2f}x")


if __name__ == "__main__":
    main()
