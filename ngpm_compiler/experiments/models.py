"""Guides for the evaluation: train (on a prefix of a trace set's kept jobs) and export.

A model spec is (name, feature set, K, number of traces or None for all). Traces are taken
by increasing job id, so the 10-trace set is a subset of the 30-trace set, and so on.
Finished .onnx files are reused when their sidecar JSON records the same spec and data.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.files import atomic_write

from ngpm_compiler.jobs import pool


@dataclass(frozen=True)
class ModelSpec:
    name: str
    features: str = "all"
    K: int = 4
    traces: int | None = None  # first n kept traces (None: all)
    epochs: int = 40


def subset(data: dict[int, Any], kept_jobs: np.ndarray, n: int | None) -> dict[int, Any]:
    """Site data restricted to the first `n` kept jobs (by job id)."""
    from ngpm_compiler.learning.trace_data import SiteData

    if n is None or n >= len(kept_jobs):
        return dict(data)
    keep = np.sort(kept_jobs)[:n]
    out = {}
    for i, d in data.items():
        m = np.isin(d.jobs, keep)
        if m.any():
            out[i] = SiteData(d.features[m], d.values[m], d.prior_args[m], d.jobs[m])
    return out


def _key(spec: ModelSpec, traces_dir: str, manifest: dict[str, Any]) -> dict[str, Any]:
    return {
        "spec": asdict(spec),
        "traces": str(Path(traces_dir).resolve()),
        "jobs_done": manifest.get("jobs_done"),
        "kept": manifest.get("kept"),
        "grammar_hash": manifest.get("grammar_hash"),
    }


def train_one(spec: ModelSpec, traces_dir: str, out_dir: str, seed: int = 0) -> str:
    """Train and export one model; returns the .onnx path (reused when up to date)."""
    from ngpm_compiler.learning.export import write_onnx
    from ngpm_compiler.learning.trace_data import load_traces
    from ngpm_compiler.learning.train import TrainConfig, train_guide

    out = Path(out_dir) / f"{spec.name}.onnx"
    meta_path = out.with_suffix(".json")
    ts = load_traces(traces_dir)
    key = _key(spec, traces_dir, ts.manifest)
    if out.is_file() and meta_path.is_file():
        old = json.loads(meta_path.read_text(encoding="utf-8"))
        if old.get("key") == key:
            return str(out)
    data = subset(ts.data, ts.kept_jobs, spec.traces)
    cfg = TrainConfig(feature_set=spec.features, K=spec.K, epochs=spec.epochs, seed=seed)
    model = train_guide(
        ts.sites,
        ts.layouts,
        data,
        cfg,
        grammar=ts.manifest["key"]["grammar"],
        grammar_hash=ts.manifest["grammar_hash"],
    )
    write_onnx(model, out)
    s = model.summary
    info = {
        "key": key,
        "traces": s["traces"],
        "val_traces": s["val_traces"],
        "best_epoch": s["best_epoch"],
        "epochs_run": s["epochs_run"],
        "val_nll": s["val_nll"],
        "seconds": s["seconds"],
    }
    atomic_write(meta_path, (json.dumps(info, indent=1) + "\n").encode("utf-8"))
    return str(out)


def _train_job(args: tuple[ModelSpec, str, str, int]) -> tuple[str, str]:
    import torch

    torch.set_num_threads(1)
    spec = args[0]
    return spec.name, train_one(*args)


def train_models(
    specs: list[ModelSpec], traces_dir: str, out_dir: str, workers: int = 1, seed: int = 0
) -> dict[str, str]:
    """Train every spec (in `workers` processes); {name: onnx path}."""
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    jobs = [(s, traces_dir, out_dir, seed) for s in specs]
    if workers <= 1 or len(jobs) <= 1:
        return dict(_train_job(j) for j in jobs)
    # biggest first, so the pool ends together
    jobs.sort(key=lambda j: -(j[0].traces or 10**9))
    with pool.spawn_pool(workers) as procs:
        return dict(procs.imap_unordered(_train_job, jobs))


def model_info(onnx_path: str) -> dict[str, Any]:
    """The sidecar JSON written beside a trained model; else the training summary that
    `ngpmc export` stores in the ONNX metadata ({} if neither is readable)."""
    p = Path(onnx_path).with_suffix(".json")
    if p.is_file():
        info: dict[str, Any] = json.loads(p.read_text(encoding="utf-8"))
        return info
    try:
        import onnxruntime as ort

        sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
        t = json.loads(sess.get_modelmeta().custom_metadata_map["training"])
    except Exception:  # not an ngpm guide, or no summary: the table shows blanks
        return {}
    spec = {"features": t.get("feature_set", "all"), "K": t.get("K", 4)}
    return {
        "key": {"spec": spec},
        **{
            k: t.get(k)
            for k in ("traces", "val_traces", "best_epoch", "epochs_run", "val_nll", "seconds")
        },
    }
