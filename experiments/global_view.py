"""Would a guide gain from a global view of the target? (experiments/notes/own_samples.md)

    python experiments/global_view.py OWN_TRACES OUT
    ngpmc train OWN_TRACES -o A.pt --features all+context
    ngpmc train OUT -o B.pt --features all+context     # compare their validation NLL

OWN_TRACES: ground-truth traces (`ngpmc traces GRAMMAR --own-samples`). Each kept job's
envelope is made again (trace_jobs.own_sample with the job's seed) and its coarsest pyramid
level (6 x 6 at 50 x 50, image axes, the whole canvas) is appended to every row of the job,
inside the `context` group, so `ngpmc train` reads it unchanged. The runtime computes no
such columns: this measures only whether the information would lower the guide's NLL.
It also prints a probe: a small classifier of site 0's first choice (derivation depth 0)
from the rows without and with the view (held-out cross-entropy and accuracy, 80/20 split).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from ngpm_runtime.image.raster import N_LEVELS, pyramid
from top_choice import DEPTH_COL  # experiments/, beside this

from ngpm_compiler.language.compile import load_grammar
from ngpm_compiler.learning.trace_jobs import job_spec, own_sample
from ngpm_compiler.learning.trace_store import TraceStore, save_npz


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("traces")
    ap.add_argument("out")
    a = ap.parse_args()
    src, out = TraceStore(a.traces), Path(a.out)
    m = src.manifest()
    if m is None or not m["key"].get("own_samples"):
        raise SystemExit(f"{a.traces}: not traces of `ngpmc traces --own-samples`")
    program = load_grammar(m["config"]["grammar"])
    size, seed = int(m["key"]["size"]), int(m["key"]["seed"])
    done = src.finished()
    views = {}
    for job in done["jobs"][done["kept"]].tolist():
        found = own_sample(program, job_spec(seed, job, 1)[1], size, m["key"]["max_modules"])
        assert found is not None
        views[job] = pyramid(found[1].mask)[N_LEVELS - 1].ravel()
    width = len(next(iter(views.values())))
    arrays = dict(done)
    for i in {int(k[2:]) for k in done if k.startswith("f_")}:
        rows, jobs = done[f"f_{i}"], done[f"j_{i}"]
        extra = np.stack([views[int(j)] for j in jobs]).astype(np.float32)
        arrays[f"f_{i}"] = np.concatenate([rows, extra], axis=1)
    out.mkdir(parents=True, exist_ok=True)
    save_npz(out / "shard_00000000.npz", arrays)
    for lay in m["layouts"].values():
        lay["context"][1] += width
    m.update(shards=["shard_00000000.npz"])
    (out / "manifest.json").write_text(json.dumps(m), encoding="utf-8")
    print(f"{out}: {len(views)} traces, {width} columns of the target's coarsest level added")
    rows = arrays["f_0"][np.isclose(arrays["f_0"][:, DEPTH_COL], 0.0)]
    values = done["v_0"][np.isclose(done["f_0"][:, DEPTH_COL], 0.0)].astype(np.int64)
    for name, x in (("without the view", rows[:, :-width]), ("with the view", rows)):
        ce, acc = probe(x, values)
        print(f"site 0 at depth 0, {name}: cross-entropy {ce:.3f}, accuracy {acc:.3f}")


def probe(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Held-out cross-entropy and accuracy of a one-hidden-layer classifier of y from x."""
    import torch

    torch.manual_seed(0)
    xt = torch.tensor((x - x.mean(0)) / (x.std(0) + 1e-6), dtype=torch.float32)
    yt = torch.tensor(y)
    cut = int(0.8 * len(xt))
    net = torch.nn.Sequential(
        torch.nn.Linear(x.shape[1], 64), torch.nn.ReLU(), torch.nn.Linear(64, int(y.max()) + 1)
    )
    opt = torch.optim.Adam(net.parameters(), 1e-3, weight_decay=1e-4)
    for _ in range(1500):
        opt.zero_grad()
        torch.nn.functional.cross_entropy(net(xt[:cut]), yt[:cut]).backward()
        opt.step()
    with torch.no_grad():
        out = net(xt[cut:])
        ce = torch.nn.functional.cross_entropy(out, yt[cut:]).item()
        acc = (out.argmax(1) == yt[cut:]).float().mean().item()
    return ce, acc


if __name__ == "__main__":
    main()
