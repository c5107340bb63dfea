"""Train the per-site guide networks on recorded site visits (forward KL, Adam).

All recorded visits of a site are batched (minibatches of visits, not one trace per step).
Whole traces (jobs) are held out for validation; the validation NLL per trace is reported
after every epoch, training stops early when it stops improving, and the best epoch's weights
are kept. A checkpoint is written atomically after each epoch, so an interrupted run resumes.
"""

from __future__ import annotations

import hashlib
import io
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.files import atomic_write
from ngpm_runtime.image.features import last_group
from ngpm_runtime.program import Site

from ngpm_compiler.learning.nets import (
    FEATURE_SETS,
    MIN_HIDDEN,
    GuideModel,
    NetSpec,
    SiteNet,
    continuous_z,
    select_columns,
)
from ngpm_compiler.learning.trace_data import JOB_STRIDE, SiteData
from ngpm_compiler.progress import Progress

CHECKPOINT_FORMAT = "ngpm-train-checkpoint/1"


@dataclass
class TrainConfig:
    feature_set: str = "all"
    K: int = 4
    epochs: int = 40
    batch_size: int = 256
    lr: float = 0.005
    val_fraction: float = 0.1
    patience: int = 4
    seed: int = 0
    threads: int = 1
    hidden: int = 0  # hidden units per site network; 0: hidden_per_input of its inputs
    hidden_per_input: float = 0.5  # (at least 8)


@dataclass
class _Split:
    x: torch.Tensor
    target: torch.Tensor
    jac: float  # sum of the log Jacobians (constant in the parameters)


def atomic_torch_save(obj: Any, path: str | Path) -> None:
    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic_write(path, buf.getvalue())


def save_model(model: GuideModel, path: str | Path) -> None:
    atomic_torch_save(model.state(), path)


def load_model(path: str | Path) -> GuideModel:
    state = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(state, dict):
        raise ValueError(f"{path}: not an ngpm guide model")
    return GuideModel.from_state(state)


def split_jobs(jobs: np.ndarray, fraction: float, seed: int) -> np.ndarray:
    """The held-out job ids: a seeded random `fraction` of the distinct jobs (none if < 2),
    drawn per merged traces directory (its block of JOB_STRIDE ids; block 0 seeded `seed`,
    block k [seed, k]), so a directory's split stays when more directories join it and a
    warm-started round never validates on traces its initial weights were trained on."""
    unique = np.unique(jobs)
    blocks = unique // JOB_STRIDE
    out = [
        _split_block(unique[blocks == b], fraction, seed if b == 0 else [seed, int(b)])
        for b in np.unique(blocks)
    ]
    return np.sort(np.concatenate(out)) if out else unique[:0]


def _split_block(unique: np.ndarray, fraction: float, seed: int | list[int]) -> np.ndarray:
    n_val = int(round(fraction * len(unique))) if len(unique) >= 2 else 0
    n_val = min(max(n_val, 1 if fraction > 0 and len(unique) >= 2 else 0), len(unique) - 1)
    return np.random.default_rng(seed).permutation(unique)[:n_val]


def weights_hash(model: GuideModel) -> str:
    """A short digest of a model's networks (specs and weights)."""
    h = hashlib.sha256()
    for _, net in sorted(model.nets.items()):
        h.update(repr(net.spec.to_json()).encode())
        for name, t in sorted(net.state_dict().items()):
            h.update(name.encode())
            h.update(t.detach().cpu().numpy().tobytes())
    return h.hexdigest()[:16]


def warm_start(model: GuideModel, init: GuideModel) -> list[int]:
    """Copy `init`'s weights and input standardization into `model`'s networks of the same
    shape (equal NetSpec); the sites so started."""
    done = []
    for i, net in model.nets.items():
        old = init.nets.get(i)
        if old is not None and old.spec == net.spec:
            net.load_state_dict(old.state_dict())
            done.append(i)
    return done


def fingerprint(data: dict[int, SiteData]) -> str:
    h = hashlib.sha256()
    for i in sorted(data):
        d = data[i]
        for arr in (d.jobs, d.values, d.features):
            h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()[:16]


def build_model(
    sites: list[Site],
    layouts: dict[int, dict[str, slice]],
    data: dict[int, SiteData],
    config: TrainConfig,
    grammar: str,
    grammar_hash: str,
    train_rows: dict[int, np.ndarray] | None = None,
) -> GuideModel:
    """Untrained networks for every site with data; inputs standardized on training rows."""
    if config.feature_set not in FEATURE_SETS:
        raise ValueError(f"unknown feature set {config.feature_set!r}")
    nets: dict[int, SiteNet] = {}
    for site in sites:
        d = data.get(site.index)
        if d is None or len(d.values) == 0:
            continue
        cols = select_columns(layouts[site.index], config.feature_set)
        rows = d.features if train_rows is None else d.features[train_rows[site.index]]
        if len(rows) == 0:
            rows = d.features
        sel = rows[:, cols].astype(np.float64)
        # rows end at the last group the guide reads (features.last_group)
        last = last_group(config.feature_set)
        n_f = layouts[site.index][last].stop
        spec = NetSpec(
            site_index=site.index,
            kind=site.kind,
            n_f=n_f,
            cols=cols,
            K=config.K,
            k=site.k,
            hidden=config.hidden or max(MIN_HIDDEN, int(len(cols) * config.hidden_per_input)),
        )
        nets[site.index] = SiteNet(
            spec, sel.mean(0), sel.std(0), prior_probs=site.probs, seed=config.seed + site.index
        )
    json_layouts = {i: {g: [s.start, s.stop] for g, s in lay.items()} for i, lay in layouts.items()}
    return GuideModel(
        grammar=grammar,
        grammar_hash=grammar_hash,
        sites=[s.to_json() for s in sites],
        feature_set=config.feature_set,
        K=config.K,
        nets=nets,
        layouts=json_layouts,
    )


def _splits(site: Site, d: SiteData, rows: np.ndarray) -> _Split:
    target, jac = continuous_z(site.kind, d.values[rows], d.prior_args[rows])
    return _Split(
        torch.from_numpy(np.ascontiguousarray(d.features[rows], dtype=np.float32)),
        torch.from_numpy(target.astype(np.float32)),
        float(jac.sum()),
    )


def _nll(net: SiteNet, split: _Split, chunk: int = 8192) -> float:
    """Total negative log q of a split, in value units."""
    with torch.no_grad():
        total = sum(
            float(net.log_prob(split.x[i : i + chunk], split.target[i : i + chunk]).sum())
            for i in range(0, len(split.target), chunk)
        )
    return -(total + split.jac)


def train_guide(
    sites: list[Site],
    layouts: dict[int, dict[str, slice]],
    data: dict[int, SiteData],
    config: TrainConfig,
    *,
    grammar: str = "",
    grammar_hash: str = "",
    checkpoint: str | Path | None = None,
    progress: bool = False,
    on_epoch: Callable[[dict[str, Any]], None] | None = None,
    stop: Callable[[], bool] | None = None,
    init: GuideModel | None = None,
) -> GuideModel:
    """Fit one network per visited site; returns the best epoch's model with a summary.
    `stop` is asked after each epoch (once checkpointed): True ends the training there, as
    early stopping does (a time limit: the summary's `stopped` says "stop"). `init` (an
    earlier round's model) warm-starts the networks of the same shape (`warm_start`).

    Long because the epoch loop, early stopping and checkpoint resumption share the
    optimizer and best-epoch state."""
    torch.set_num_threads(max(1, config.threads))
    start = time.perf_counter()
    all_jobs = np.concatenate([d.jobs for d in data.values()]) if data else np.zeros(0, int)
    val_jobs = split_jobs(all_jobs, config.val_fraction, config.seed)
    n_jobs = len(np.unique(all_jobs))
    train_rows, val_rows = {}, {}
    for i, d in data.items():
        is_val = np.isin(d.jobs, val_jobs)
        train_rows[i], val_rows[i] = np.flatnonzero(~is_val), np.flatnonzero(is_val)
    model = build_model(sites, layouts, data, config, grammar, grammar_hash, train_rows)
    warm = warm_start(model, init) if init is not None else []
    by_index = {s.index: s for s in sites}
    train = {i: _splits(by_index[i], data[i], train_rows[i]) for i in model.nets}
    val = {i: _splits(by_index[i], data[i], val_rows[i]) for i in model.nets}
    optims = {i: torch.optim.Adam(net.parameters(), lr=config.lr) for i, net in model.nets.items()}
    history: list[dict[str, Any]] = []
    best: dict[str, Any] | None = None
    key = {
        "config": {k: v for k, v in asdict(config).items() if k not in ("epochs", "threads")},
        "data": fingerprint(data),
        "init": weights_hash(init) if init is not None else "",
    }
    first_epoch, bad, stopped = 0, 0, ""
    if checkpoint and Path(checkpoint).is_file():
        ck = torch.load(checkpoint, map_location="cpu", weights_only=True)
        if ck.get("format") == CHECKPOINT_FORMAT and ck.get("key") == key:
            model = GuideModel.from_state(ck["model"])
            optims = {
                i: torch.optim.Adam(net.parameters(), lr=config.lr) for i, net in model.nets.items()
            }
            for i, opt in optims.items():
                opt.load_state_dict(ck["optims"][str(i)])
            history, best, bad = ck["history"], ck["best"], ck["bad"]
            first_epoch = len(history)
    n_train_jobs = max(1, n_jobs - len(val_jobs))
    n_val_jobs = len(val_jobs)
    bar = Progress("train", config.epochs, "epoch", initial=first_epoch, enabled=progress)
    for epoch in range(first_epoch, config.epochs):
        if bad >= config.patience:
            break
        for i, net in model.nets.items():
            split, opt = train[i], optims[i]
            m = len(split.target)
            order = np.random.default_rng([config.seed, epoch, i]).permutation(m)
            for b in range(0, m, config.batch_size):
                idx = torch.from_numpy(order[b : b + config.batch_size])
                loss = -net.log_prob(split.x[idx], split.target[idx]).mean()
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
        train_nll = sum(_nll(net, train[i]) for i, net in model.nets.items()) / n_train_jobs
        val_nll = (
            sum(_nll(net, val[i]) for i, net in model.nets.items()) / n_val_jobs
            if n_val_jobs
            else train_nll
        )
        row = {
            "epoch": epoch + 1,
            "train_nll": train_nll,
            "val_nll": val_nll,
            "seconds": round(time.perf_counter() - start, 3),
        }
        history.append(row)
        if best is None or val_nll < best["val_nll"] - 1e-6 * abs(best["val_nll"]):
            best, bad = {"val_nll": val_nll, "epoch": epoch + 1, "model": model.state()}, 0
        else:
            bad += 1
        bar.set_postfix(val_nll=f"{val_nll:.3f}", train_nll=f"{train_nll:.3f}")
        bar.update()
        if on_epoch:
            on_epoch(row)
        if checkpoint:
            atomic_torch_save(
                {
                    "format": CHECKPOINT_FORMAT,
                    "key": key,
                    "model": model.state(),
                    "optims": {str(i): o.state_dict() for i, o in optims.items()},
                    "history": history,
                    "best": best,
                    "bad": bad,
                },
                checkpoint,
            )
        if stop is not None and epoch + 1 < config.epochs and bad < config.patience and stop():
            stopped = "stop"
            break
    bar.close()
    if best is not None:
        model = GuideModel.from_state(best["model"])
    model.summary = {
        "traces": n_jobs,
        "val_traces": n_val_jobs,
        "feature_set": config.feature_set,
        "K": config.K,
        "rows": {str(i): int(len(d.values)) for i, d in sorted(data.items())},
        "sites_trained": sorted(model.nets),
        "warm_started": sorted(warm),
        "epochs_run": len(history),
        "stopped": stopped,
        "best_epoch": best["epoch"] if best else 0,
        "val_nll": best["val_nll"] if best else None,
        "history": history,
        "seconds": round(time.perf_counter() - start, 3),
        "config": asdict(config),
    }
    return model


class GuideFileError(NgpmError):
    """A model.pt file cannot be read."""


def load_model_file(path: str) -> GuideModel:
    if not Path(path).is_file():
        raise GuideFileError(f"{path}: no such model file")
    try:
        return load_model(path)
    except Exception as err:  # torch raises many types for foreign files
        raise GuideFileError(
            f"{path}: not a model written by `ngpmc train` ({err.__class__.__name__})"
        ) from None
