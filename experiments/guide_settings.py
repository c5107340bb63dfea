"""A guide's held-out similarity under other proposal settings (experiments/notes).

    python experiments/guide_settings.py GRAMMAR GUIDE DIR[,DIR...] \
        --ns 10,30 --settings 1:1:none,1:1:0.05,0.5:1:none --runs 16

Each setting is T:Tc:ESS (temperature, choice temperature, ESS threshold or `none` for
resampling every step); the guide's networks are the file's, its own settings replaced.
Guided SMC at each N on every target of the DIRs (target sets as `ngpmc targets build`
writes them), `--runs` seeds a target: prints the mean over targets of the median
similarity, the measure of docs/results.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np
from ngpm_runtime.grow import grow
from ngpm_runtime.inference.guide import Guide, ProposalSettings
from ngpm_runtime.program import Program

from ngpm_compiler.language.compile import load_grammar
from ngpm_compiler.learning.trace_jobs import load_targets


def parse_setting(text: str) -> ProposalSettings:
    t, tc, ess = text.split(":")
    return ProposalSettings(float(t), float(tc), None if ess == "none" else float(ess))


def load_sets(dirs: str, program: Program, limit: int = 0) -> list[Any]:
    """The targets of the comma-separated target set folders (the first `limit` of each)."""
    targets = []
    for d in dirs.split(","):
        ts = load_targets(d, 50, False, program)
        targets.extend(ts[:limit] if limit else ts)
    return targets


def score(program: Program, targets: list[Any], guide: Guide, n: int, runs: int) -> float:
    """Mean over targets of the median similarity of `runs` guided runs at N = n (run r of
    target i seeded 1000 i + r)."""
    medians = [
        np.median([grow(program, t, guide, n, 1000 * i + r).similarity for r in range(runs)])
        for i, t in enumerate(targets)
    ]
    return float(np.mean(medians))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("grammar")
    ap.add_argument("guide")
    ap.add_argument("targets", help="target set folders, comma-separated")
    ap.add_argument("--ns", default="10")
    ap.add_argument("--settings", default="1:1:none")
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--limit", type=int, default=0, help="first targets of each set (0: all)")
    a = ap.parse_args()
    program = load_grammar(a.grammar)
    targets = load_sets(a.targets, program, a.limit)
    for n in (int(x) for x in a.ns.split(",")):
        for text in a.settings.split(","):
            guide = Guide.load(a.guide, program, settings=parse_setting(text))
            t0 = time.time()
            sim = score(program, targets, guide, n, a.runs)
            print(
                f"N={n} {text}: {sim:.3f} ({len(targets)} targets, {time.time() - t0:.0f} s)",
                flush=True,
            )


if __name__ == "__main__":
    main()
