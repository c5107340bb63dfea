"""How well a guide predicts a choice site's values at each derivation depth (experiments/
notes/far_lookahead.md).

    python experiments/choice_depths.py TRACES GUIDE [--site 0] [--shards 16]

On the last `--shards` shards of a traces folder (ground-truth traces: the values are the
samples' own), per derivation depth (the feature row's depth column: depth / derivation
length): the rows, the guide's cross-entropy (its untempered probabilities), that of the
values' own marginal at that depth, and the share of rows whose most probable value is the
recorded one; then the cross-entropy over all rows. A depth whose cross-entropy equals the
marginal's is one the guide's features say nothing about.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import onnxruntime as ort
from top_choice import DEPTH_COL  # experiments/, beside this


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("traces")
    ap.add_argument("guide")
    ap.add_argument("--site", type=int, default=0)
    ap.add_argument("--shards", type=int, default=16)
    a = ap.parse_args()
    folder = Path(a.traces)
    f_parts, v_parts = [], []
    for shard in sorted(folder.glob("shard_*.npz"))[-a.shards :]:
        z = np.load(shard)
        f_parts.append(z[f"f_{a.site}"])
        v_parts.append(z[f"v_{a.site}"])
    f, v = np.concatenate(f_parts), np.concatenate(v_parts).astype(int)
    sess = ort.InferenceSession(a.guide)
    n_f = sess.get_inputs()[a.site].shape[1]
    p = sess.run([f"p_{a.site}"], {f"f_{a.site}": f[:, :n_f].astype(np.float32)})[0]
    p = p / p.sum(1, keepdims=True)
    depth = f[:, DEPTH_COL]
    for d in np.unique(depth):
        m = depth == d
        marginal = np.bincount(v[m], minlength=p.shape[1]) / m.sum()
        ce = -np.log(p[m, v[m]] + 1e-12).mean()
        ce0 = -np.log(marginal[v[m]]).mean()
        acc = (p[m].argmax(1) == v[m]).mean()
        print(
            f"depth {d:.3f}: {m.sum()} rows, cross-entropy {ce:.3f} (marginal {ce0:.3f}), "
            f"top value right {acc:.3f}"
        )
    ce_all = -np.log(p[np.arange(len(v)), v] + 1e-12).sum()
    print(f"all depths: {len(v)} rows, cross-entropy {ce_all / len(v):.4f} a row")


if __name__ == "__main__":
    main()
