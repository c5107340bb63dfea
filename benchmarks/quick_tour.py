"""The README's quick tour at full scale, timed: the figures the README quotes.

Runs every command of README.md's "Quick tour" as written (read from the README, in a work
folder holding the tour's grammar and the demo's horse as `my_picture.png`), then grows the
horse with seeds 0, 1 and 2 with each `grow` line of the tour (the tuned guide and the
prior), and writes a Markdown report: seconds per command, the similarities, and the
machine's load while it ran (the machine may be shared: compare the load, not just the
seconds); the tour's `ngpmc learn` report is copied beside it (quick_tour_learn.md).

Usage: python benchmarks/quick_tour.py [-o docs/results/quick_tour.md] [--work DIR]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

from ngpm_runtime.files import atomic_write

from ngpm_compiler.cli import tour

REPO = Path(__file__).resolve().parents[1]
SEEDS = (0, 1, 2)


def grow_table(work: Path, grows: list[list[str]]) -> list[str]:
    """Each grow line of the tour with seeds 0, 1, 2: similarities and seconds."""

    rows = [
        "| grow | " + " | ".join(f"seed {s}" for s in SEEDS) + " | mean | seconds |",
        "|---|" + "---|" * (len(SEEDS) + 2),
    ]
    for argv in grows:
        sims, secs = [], []
        for seed in SEEDS:
            out = work / f"seed{seed}.png"
            steps = tour.run_commands(work, [[*argv, "--seed", str(seed), "-o", str(out)]])
            sims.append(tour.similarity(steps[0].output))
            secs.append(steps[0].seconds)
        guide = argv[argv.index("--guide") + 1] if "--guide" in argv else "(bundled)"
        rows.append(
            f"| `--guide {guide}` | "
            + " | ".join(f"{s:.3f}" for s in sims)
            + f" | {statistics.mean(sims):.3f} | {statistics.mean(secs):.2f} |"
        )
    return rows


def copy_learn_report(steps: list[tour.Step], work: Path, results: Path) -> None:
    """The tour's `ngpmc learn` report (and its plot) beside the results page:
    quick_tour_learn.md, quick_tour_curve.png."""
    for s in steps:
        if s.argv[0] == "learn":
            out = work / s.argv[s.argv.index("-o") + 1]
            text = (out / "report.md").read_text(encoding="utf-8")
            if (out / "curve.png").is_file():
                atomic_write(results / "quick_tour_curve.png", (out / "curve.png").read_bytes())
                text = text.replace("(curve.png)", "(quick_tour_curve.png)")
            atomic_write(results / "quick_tour_learn.md", text.encode("utf-8"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", default=str(REPO / "docs" / "results" / "quick_tour.md"))
    ap.add_argument("--work", help="work folder (default: a temporary one)")
    args = ap.parse_args()
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.work or tmp)
        load0, t0 = os.getloadavg()[0], time.perf_counter()
        steps = tour.run_tour(readme, work)
        failed = [s for s in steps if s.code != 0]
        if failed:
            print(failed[0].output)
            raise SystemExit(f"tour command failed: ngpmc {' '.join(failed[0].argv)}")
        grows = [s.argv for s in steps if s.argv[0] == "grow"]
        table = grow_table(work, grows)
        copy_learn_report(steps, work, Path(args.out).parent)
        total, load1 = time.perf_counter() - t0, os.getloadavg()[0]
    lines = [
        "# The README's quick tour, measured",
        "",
        "Made by `python benchmarks/quick_tour.py` (every command of the tour as the "
        "README writes it, then each `grow` line with seeds 0, 1, 2 on the demo's horse).",
        "",
        f"Machine: {os.cpu_count()} cores, {platform.python_implementation()} "
        f"{platform.python_version()}; load average {load0:.1f} at the start, "
        f"{load1:.1f} at the end (a load above the core count means other jobs shared "
        "the machine and the seconds are longer than on an idle one).",
        "",
        "| command | seconds |",
        "|---|---|",
    ]
    lines += [f"| `ngpmc {' '.join(s.argv)}` | {s.seconds:.1f} |" for s in steps]
    lines += [
        f"| **the tour, in all** | **{sum(s.seconds for s in steps):.0f}** |",
        "",
        "Similarity of the best particle (1 = the target exactly, 0 = no better than a "
        "blank canvas, below 0 = worse than blank):",
        "",
        *table,
        "",
        f"Whole run, with the seeds: {total:.0f} s.",
        "",
    ]
    text = "\n".join(lines)
    atomic_write(args.out, text.encode("utf-8"))
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
