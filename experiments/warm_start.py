"""Warm-started against from-scratch training on growing trace sets (experiments/notes/
envelope_training.md).

    python experiments/warm_start.py T1,T2,T3 -o OUT --features all+context+far \
        --hidden 220 [--scratch] [--init MODEL]

Trains on T1, then T1+T2 starting from that model's weights, then T1+T2+T3 from that one
(as `ngpmc learn`'s warm-started rounds do; `--init`: a model of T1 already trained, which
skips the first step), writing OUT/warm_<k>.pt and .onnx; with `--scratch` it trains only the
last set from scratch (OUT/scratch.pt). Prints each training's validation NLL per trace,
best epoch and seconds: the merged sets hold out the same traces either way (train.py's
split_jobs splits each traces directory on its own).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ngpm_compiler.learning.export import write_onnx
from ngpm_compiler.learning.rounds import merge_traces
from ngpm_compiler.learning.trace_data import load_traces
from ngpm_compiler.learning.train import TrainConfig, load_model, save_model, train_guide


def fit(dirs: list[str], cfg: TrainConfig, init, out: Path) -> object:
    ts = merge_traces([load_traces(d) for d in dirs])
    model = train_guide(
        ts.sites,
        ts.layouts,
        ts.data,
        cfg,
        grammar=ts.manifest["key"]["grammar"],
        grammar_hash=ts.manifest["grammar_hash"],
        checkpoint=out.with_suffix(".pt.ckpt"),
        init=init,
    )
    save_model(model, out)
    write_onnx(model, out.with_suffix(".onnx"))
    s = model.summary
    print(
        f"{out.name}: {s['traces']} traces, warm {bool(s['warm_started'])}, validation NLL "
        f"{s['val_nll']:.3f}, best epoch {s['best_epoch']} of {s['epochs_run']}, "
        f"{s['seconds']:.0f} s",
        flush=True,
    )
    return model


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("traces", help="trace folders, comma-separated, in round order")
    ap.add_argument("-o", "--out", required=True)
    ap.add_argument("--features", default="all+context+far")
    ap.add_argument("--hidden", type=int, default=0)
    ap.add_argument("--patience", type=int, default=10)
    ap.add_argument("--epochs", type=int, default=100)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--scratch", action="store_true")
    ap.add_argument("--init", default="")
    a = ap.parse_args()
    dirs = a.traces.split(",")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = TrainConfig(
        feature_set=a.features,
        epochs=a.epochs,
        patience=a.patience,
        hidden=a.hidden,
        threads=a.threads,
    )
    if a.scratch:
        fit(dirs, cfg, None, out / "scratch.pt")
        return
    model = load_model(a.init) if a.init else None
    for k in range(2 if a.init else 1, len(dirs) + 1):
        model = fit(dirs[:k], cfg, model, out / f"warm_{k}.pt")


if __name__ == "__main__":
    main()
