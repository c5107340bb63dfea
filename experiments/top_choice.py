"""Do a learn run's teachers pick a site's first choice by the target? (experiments/notes)

    python experiments/top_choice.py LEARN_DIR [--site 0] [--rounds 0-4]

For every trace of the rounds' trace folders (LEARN_DIR/rounds/round_<r>/traces_*), the
value of the site's visits at derivation depths 0, 1/4 and 1/2 of the derivation length
(the feature row's depth column), tabulated against the quartile of the trace's target's
height (its ink's rows, as a share of the image). A choice that depends on the target shows
different shares per quartile; the same shares everywhere say the teacher's best particle
chose it regardless of the target.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from ngpm_runtime.image.targets import load_dataset

DEPTH_COL = 6  # the local group's depth / derivation length (image/features.py)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("learn_dir")
    ap.add_argument("--site", type=int, default=0)
    ap.add_argument("--rounds", default="0-4")
    a = ap.parse_args()
    base = Path(a.learn_dir)
    lo, hi = (int(x) for x in a.rounds.split("-"))
    heights: dict[str, float] = {}
    for t in load_dataset(base / "targets" / "envelopes", size=50):
        for u in (t, t.mirrored()):
            rows = np.flatnonzero(np.asarray(u.mask).any(1))
            heights[u.name] = (rows.max() - rows.min()) / u.mask.shape[0]
    seen: list[tuple[float, np.ndarray, np.ndarray]] = []
    for r in range(lo, hi + 1):
        for d in sorted((base / "rounds" / f"round_{r}").glob("traces_*")):
            names = json.loads((d / "manifest.json").read_text())["key"]["targets"]
            for shard in sorted(d.glob("shard_*.npz")):
                z = np.load(shard)
                f, v, j = z[f"f_{a.site}"], z[f"v_{a.site}"], z[f"j_{a.site}"]
                for job, tg in zip(z["jobs"], z["target"], strict=True):
                    sel = j == job
                    seen.append((heights[names[tg]], f[sel, DEPTH_COL], v[sel]))
    h = np.array([x[0] for x in seen])
    edges = np.quantile(h, [0, 0.25, 0.5, 0.75, 1])
    print(f"{len(seen)} traces, rounds {lo}-{hi}, site {a.site}")
    for depth in (0.0, 0.25, 0.5):
        print(f"depth {depth:g}: share of each value by target height")
        for a0, b0 in zip(edges[:-1], edges[1:], strict=True):
            vals = [
                int(v[np.isclose(dp, depth)][0])
                for hh, dp, v in seen
                if a0 <= hh <= b0 and np.isclose(dp, depth).any()
            ]
            shares = np.bincount(vals, minlength=3) / max(1, len(vals))
            print(f"  height {a0:.2f}-{b0:.2f}: {len(vals)} traces, {np.round(shares, 2)}")


if __name__ == "__main__":
    main()
