"""Expert iteration: traces from the current guide -> train the next guide -> repeat.

A guide trained on the best particles of unguided SMC can only imitate that teacher. Guided
SMC weighs every particle by prior / proposal, so its best particle is a trace of the same
posterior, and with a good guide many particles find better ones than unguided SMC does
with the same budget. Each round records `n` traces per training-target directory with SMC
guided by the best guide so far (the first round, with no guide to start from, runs
unguided SMC), trains a guide on every round's traces together (and on `init_traces`),
exports it, and scores it on validation targets at N = `val_n`; the best round's guide is
copied to `best.onnx`. Rounds compare under equal proposal settings: a new round's guide
proposes with the default ones (no `ngpmc tune`), so an initial guide tuned by `ngpmc
tune` is scored as an untuned copy (round_0/untuned.onnx: the same networks), while the
tuned file itself teaches round 1 and is what best.onnx holds when round 0 stays the best.
Tune best.onnx afterwards. Files under `out`: round_<r>/{traces_<i>, model.pt, guide.onnx},
validation/ (the run cache of evaluation/heldout.py: appended run by run and keyed by the
content hashes of each round's guide and of the targets, so a resumed iteration scores a
retrained round anew), rounds.csv, best.onnx.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from ngpm_runtime.files import atomic_write
from ngpm_runtime.inference.guide import ProposalSettings

from ngpm_compiler.learning.shards import TraceError
from ngpm_compiler.learning.trace_data import JOB_STRIDE, SiteData, TraceSet
from ngpm_compiler.learning.trace_jobs import MIN_PRIMITIVES
from ngpm_compiler.learning.traces import TraceConfig, generate_traces
from ngpm_compiler.progress import Log

if TYPE_CHECKING:  # train.py imports torch: on use
    from ngpm_compiler.learning.nets import GuideModel
    from ngpm_compiler.learning.train import TrainConfig


@dataclass
class RoundsConfig:
    grammar: str
    targets: list[str]  # training-target directories
    validation: dict[str, str]  # name -> target directory (never trained on)
    out: str
    rounds: int = 2
    n: int = 300  # kept traces per round and target directory
    particles: int = 200  # guided SMC particles
    unguided_particles: int = 600  # particles of a round without a guide (round 1, no init)
    init_guide: str | None = None  # the guide of round 0 (scored, then proposes in round 1)
    init_traces: list[str] = field(default_factory=list)  # added to every round's training
    mirror: bool = True
    min_primitives: int = MIN_PRIMITIVES  # shorter traces are dropped
    val_targets: int = 12
    val_repeats: int = 2
    val_n: int = 10
    feature_set: str = "all"
    epochs: int = 40
    patience: int = 4  # early stopping's, in epochs
    batch_size: int = 256
    lr: float = 0.005
    hidden_per_input: float = 0.5  # hidden units per site network over its inputs
    warm_start: bool = False  # round r's training starts from round r - 1's weights
    warm_patience: int = 0  # a warm-started training's patience (0: `patience`)
    K: int = 4
    workers: int = 2
    seed: int = 0
    likelihood: str = "shape"  # circuit: targets [""], validation heldout.CIRCUIT_SETS


def train_config(cfg: RoundsConfig, warm: bool = False) -> TrainConfig:
    """The TrainConfig of a round's training (`warm`: one that starts from the round
    before's weights, which stops sooner: `warm_patience`)."""
    from ngpm_compiler.learning.train import TrainConfig

    return TrainConfig(
        feature_set=cfg.feature_set,
        K=cfg.K,
        epochs=cfg.epochs,
        patience=cfg.warm_patience if warm and cfg.warm_patience else cfg.patience,
        batch_size=cfg.batch_size,
        lr=cfg.lr,
        hidden_per_input=cfg.hidden_per_input,
        seed=cfg.seed,
        threads=cfg.workers,  # a round trains alone: on the cores its traces used
    )


def warm_init(cfg: RoundsConfig, r: int) -> GuideModel | None:
    """The model round r's training starts from: round r - 1's model.pt under
    `cfg.warm_start` (None without it, for round 0 or 1 of a run without that file)."""
    from ngpm_compiler.learning.train import load_model

    prev = Path(cfg.out) / f"round_{r - 1}" / "model.pt"
    if not cfg.warm_start or r < 1 or not prev.is_file():
        return None
    return load_model(prev)


def merge_traces(sets: list[TraceSet]) -> TraceSet:
    """One training set from several traces directories of the same grammar (job ids of the
    k-th set offset by k * JOB_STRIDE, so whole traces stay together in the validation
    split)."""
    first = sets[0]
    for ts in sets[1:]:
        if ts.manifest["grammar_hash"] != first.manifest["grammar_hash"]:
            raise TraceError("traces of different grammars cannot be merged")
        if ts.layouts != first.layouts:
            raise TraceError("traces with different feature layouts cannot be merged")
    data: dict[int, SiteData] = {}
    for k, ts in enumerate(sets):
        for site, d in ts.data.items():
            part = SiteData(d.features, d.values, d.prior_args, d.jobs + k * JOB_STRIDE)
            old = data.get(site)
            data[site] = (
                part
                if old is None
                else SiteData(
                    np.concatenate([old.features, part.features]),
                    np.concatenate([old.values, part.values]),
                    np.concatenate([old.prior_args, part.prior_args]),
                    np.concatenate([old.jobs, part.jobs]),
                )
            )
    kept = np.concatenate([ts.kept_jobs + k * JOB_STRIDE for k, ts in enumerate(sets)])
    return TraceSet(
        first.manifest, first.sites, first.layouts, data, kept, sum(ts.dropped for ts in sets)
    )


def record_round(cfg: RoundsConfig, r: int, guide: str | None, log: Log) -> list[str]:
    """Round r's traces, one directory per training-target directory."""
    dirs = []
    for i, targets in enumerate(cfg.targets):
        out = Path(cfg.out) / f"round_{r}" / f"traces_{i}"
        tc = TraceConfig(
            grammar=cfg.grammar,
            targets=targets,
            n=cfg.n,
            particles=cfg.particles if guide else cfg.unguided_particles,
            seed=cfg.seed + 1000 * r + i,
            workers=cfg.workers,
            mirror=cfg.mirror and cfg.likelihood == "shape",
            min_primitives=cfg.min_primitives,
            guide=guide,
            likelihood=cfg.likelihood,
        )
        m = generate_traces(tc, out, progress=False)
        log(
            f"round {r}: {out}: {m['kept']} traces ({m['dropped']} dropped), "
            f"{m['seconds']:.0f} s, {'guided by ' + guide if guide else 'unguided'}"
        )
        dirs.append(str(out))
    return dirs


def train_round(
    cfg: RoundsConfig, r: int, trace_dirs: list[str], log: Log
) -> tuple[str, dict[str, Any]]:
    """Train and export round r's guide on `trace_dirs`; (onnx path, training summary)."""
    from ngpm_compiler.learning.export import write_onnx
    from ngpm_compiler.learning.trace_data import load_traces
    from ngpm_compiler.learning.train import load_model, save_model, train_guide

    ts = merge_traces([load_traces(d) for d in trace_dirs])
    folder = Path(cfg.out) / f"round_{r}"
    folder.mkdir(parents=True, exist_ok=True)
    done, onnx = folder / "model.pt", folder / "guide.onnx"
    if done.is_file() and onnx.is_file():  # a finished round on the same traces: reuse
        old = load_model(done)
        if old.summary.get("traces") == len(ts.kept_jobs) and old.feature_set == cfg.feature_set:
            log(f"round {r}: reusing {onnx} ({len(ts.kept_jobs)} traces)")
            return str(onnx), old.summary
    init = warm_init(cfg, r)
    model = train_guide(
        ts.sites,
        ts.layouts,
        ts.data,
        train_config(cfg, warm=init is not None),
        grammar=ts.manifest["key"]["grammar"],
        grammar_hash=ts.manifest["grammar_hash"],
        init=init,
    )
    save_model(model, folder / "model.pt")
    path = write_onnx(model, folder / "guide.onnx")
    s = model.summary
    log(
        f"round {r}: trained on {s['traces']} traces, validation NLL {s['val_nll']:.2f}, "
        f"{s['seconds']:.0f} s"
    )
    return str(path), s


def validate(cfg: RoundsConfig, name: str, guide: str, log: Log) -> float:
    """Mean over validation targets of the median similarity (circuit: score) at N = val_n."""
    from ngpm_compiler.evaluation.heldout import run_heldout

    res = run_heldout(
        Path(cfg.out) / "validation",
        cfg.grammar,
        cfg.validation,
        {name: guide},
        k=cfg.val_targets,
        repeats=cfg.val_repeats,
        guided_n=cfg.val_n,
        unguided_ns=(),
        workers=cfg.workers,
        seed=cfg.seed,
        log=lambda _m: None,
        likelihood=cfg.likelihood,
    )
    sims = [
        float(s["mean_similarity"])
        for s in res["summary"]
        if s["model"] == name and int(s["n"]) == cfg.val_n
    ]
    score = float(np.mean(sims))
    what = "score" if cfg.likelihood == "circuit" else "similarity"
    log(f"{name}: validation {what} {score:.3f} at N = {cfg.val_n}")
    return score


def untuned(guide: str, settings: ProposalSettings, folder: Path, log: Log) -> str:
    """The guide to score for `guide` (which proposes with `settings`) under the default
    proposal settings, as every new round's guide proposes: `guide` itself, or a copy
    without its tuned settings."""
    from ngpm_compiler.learning.tune import with_settings

    if settings == ProposalSettings():
        return guide
    copy = with_settings(guide, folder / "untuned.onnx", ProposalSettings())
    log(
        f"round 0: {guide} proposes with {settings.label()} (ngpmc tune); scored with the "
        f"default settings ({copy}), as the new rounds are, so that rounds compare under "
        "equal settings"
    )
    return str(copy)


def expert_iteration(cfg: RoundsConfig, log: Log = print) -> list[dict[str, Any]]:
    """Run the rounds (resuming finished ones); one row per round, best guide copied to
    out/best.onnx."""
    settings = ProposalSettings()
    if cfg.init_guide:  # a guide that does not load or fit: one error, before workers
        from ngpm_compiler.jobs.backends import load_guide
        from ngpm_compiler.language.compile import load_grammar

        settings = load_guide(cfg.init_guide, load_grammar(cfg.grammar)).settings
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / "config.json", json.dumps(asdict(cfg), indent=1))
    rows: list[dict[str, Any]] = []
    best: tuple[float, str | None] = (-np.inf, None)
    if cfg.init_guide:
        scored = untuned(cfg.init_guide, settings, out / "round_0", log)
        score = validate(cfg, "round_0", scored, log)
        rows.append(
            {
                "round": 0,
                "teacher": "initial guide"
                if scored == cfg.init_guide
                else "initial guide (scored untuned)",
                "traces": "",
                "val_nll": "",
                "validation": round(score, 4),
                "guide": cfg.init_guide,
            }
        )
        best = (score, cfg.init_guide)
    trace_dirs = list(cfg.init_traces)
    for r in range(1, cfg.rounds + 1):
        teacher = best[1]
        trace_dirs += record_round(cfg, r, teacher, log)
        path, summary = train_round(cfg, r, trace_dirs, log)
        score = validate(cfg, f"round_{r}", path, log)
        rows.append(
            {
                "round": r,
                "teacher": f"guided N={cfg.particles}"
                if teacher
                else f"unguided N={cfg.unguided_particles}",
                "traces": summary["traces"],
                "val_nll": round(float(summary["val_nll"]), 3),
                "validation": round(score, 4),
                "guide": path,
            }
        )
        if score > best[0]:
            best = (score, path)
    if best[1] is not None:
        atomic_write(out / "best.onnx", Path(best[1]).read_bytes())
    from ngpm_compiler.evaluation.runs import write_csv

    write_csv(
        out / "rounds.csv", rows, ("round", "teacher", "traces", "val_nll", "validation", "guide")
    )
    log(f"best: {best[1]} (validation {best[0]:.3f}) -> {out / 'best.onnx'}")
    return rows
