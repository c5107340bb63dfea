"""Training traces: SMC on dataset targets, keep the best particle's trace.

SMC proposes from the grammar's prior (the paper) or, with `TraceConfig.guide`, from a
trained guide (expert iteration): guided SMC weighs each particle by prior / proposal, so
its particles are weighted samples of the same posterior and the kept best particle is a
trace of the same kind, only found with far fewer particles.

Job `i` is a pure function of (grammar, base seed, i): its target and SMC seed come from
`job_spec(base_seed, i, n_targets)`. Jobs run in worker processes (spawn-safe); every finished
job is written at once to `pending/job_<i>.npz` (atomic), and pending jobs are gathered into
shards `shard_<first>.npz`. A rerun on the same directory skips finished job ids, so an
interrupted run loses no finished trace and never repeats one.

Shard / pending npz arrays: `jobs, kept, n_prims, target, seed` (one entry per job; n_prims
is -1 when SMC failed: every particle died, so the job is dropped) and per
visited site `i`: `f_<i>` (m, n_f) float32 features, `v_<i>` (m,) values, `j_<i>` (m,) job ids.
`manifest.json` holds the configuration (checked on resume), site table, feature layouts and
counts. Job ids are handed out in increasing order and only while `kept + running < n`, so the
finished set is the shortest prefix of job ids holding `n` kept traces, however often the run
is interrupted.
"""

from __future__ import annotations

import io
import json
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.errors import NgpmError, SMCFailed
from ngpm_runtime.files import atomic_write
from ngpm_runtime.program import Program, Site
from tqdm import tqdm

from ngpm_compiler.learning import pool

TRACE_FORMAT = "ngpm-traces/1"
MIN_PRIMITIVES = 10  # the paper's code dropped shorter traces


@dataclass
class SiteData:
    """Every recorded visit of one site: raw features, chosen values, prior args, job ids."""

    features: np.ndarray  # (m, n_f) float32
    values: np.ndarray  # (m,) float64
    prior_args: np.ndarray  # (m, n_args) float64
    jobs: np.ndarray  # (m,) int64: the trace each row belongs to


class TraceError(NgpmError):
    """A traces directory cannot be used (other configuration, corrupt shard)."""


@dataclass
class TraceConfig:
    grammar: str  # .lsys source or a generated *_sampler.py
    targets: str  # dataset directory
    n: int  # kept traces wanted
    particles: int = 600
    seed: int = 0
    workers: int = 2
    mirror: bool = False  # add mirrored copies of targets that have none
    size: int = 50  # target size (pixels)
    min_primitives: int = MIN_PRIMITIVES
    shard_size: int = 50
    guide: str | None = None  # guide .onnx proposing in SMC (None: the prior)


def load_targets(directory: str | Path, size: int, mirror: bool) -> list[Any]:
    """The dataset's targets, plus mirrored copies of those without one when `mirror`."""
    from ngpm_runtime.image.targets import load_dataset

    targets = list(load_dataset(directory, size=size))
    if mirror:
        names = {t.name for t in targets}
        extra = [t.mirrored() for t in targets
                 if not t.name.endswith("_m") and t.name + "_m" not in names]
        targets.extend(extra)
    return targets


def job_spec(base_seed: int, job: int, n_targets: int) -> tuple[int, int]:
    """(target index, SMC seed) of job `job`: a pure function of its arguments."""
    a, b = np.random.SeedSequence([int(base_seed), int(job)]).generate_state(2)
    return int(a) % n_targets, int(b)


def run_job(program: Program, target: Any, seed: int, particles: int, guide: Any = None
            ) -> tuple[list[tuple[int, np.ndarray, float]], int]:
    """SMC (guided by `guide`, else unguided) on one target; the best particle's trace and
    primitive count.

    The run records values only; the best particle alone is then replayed with its values
    to compute its features (the same rows a run with features for every particle gives)."""
    from ngpm_runtime.errors import ProgramError
    from ngpm_runtime.grow import grow
    from ngpm_runtime.inference.smc import replay

    start = target.start_pose(program.viewport)
    best = grow(program, target, guide, particles, seed, record_trace="values").smc.best
    values = [(s, v) for s, _, v in best.trace or []]
    again = replay(program, values, start=start, canvas_size=target.size,
                   target_mask=target.mask)
    if again.primitives != best.primitives:
        raise ProgramError(f"program {program.name}: replaying the best particle's values "
                           "drew other primitives (generated code is not pure)")
    return list(again.trace or []), len(best.primitives)


def site_layouts(program: Program, target_mask: np.ndarray | None) -> dict[int, dict[str, slice]]:
    """FeatureMaker.layout for every site."""
    from ngpm_runtime.image.features import FeatureMaker

    fm = FeatureMaker(program, program.viewport, target_mask)
    return {s.index: fm.layout(s) for s in program.sites}


def prior_arg_columns(site: Site, layout: dict[str, slice]) -> slice:
    """Columns of the prior arguments: the last `n_args` of the local group (section 6)."""
    stop = layout["local"].stop
    return slice(stop - site.n_args(), stop)


# --------------------------------------------------------------------------- files


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write(path, buf.getvalue())


def _load_npz(path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    except Exception as err:
        raise TraceError(f"{path}: corrupt trace shard ({err.__class__.__name__})") from None


def job_arrays(job: int, target: int, seed: int, trace: list[tuple[int, np.ndarray, float]],
               n_prims: int, kept: bool) -> dict[str, np.ndarray]:
    """The npz arrays of one finished job (a dropped job records no site visits)."""
    out = {"jobs": np.array([job], np.int64), "kept": np.array([kept]),
           "n_prims": np.array([n_prims], np.int64), "target": np.array([target], np.int64),
           "seed": np.array([seed], np.uint64)}
    if kept:
        by_site: dict[int, list[tuple[np.ndarray, float]]] = {}
        for site, feats, value in trace:
            by_site.setdefault(int(site), []).append((feats, value))
        for site, rows in by_site.items():
            out[f"f_{site}"] = np.stack([np.asarray(f, np.float32) for f, _ in rows])
            out[f"v_{site}"] = np.array([v for _, v in rows], np.float64)
            out[f"j_{site}"] = np.full(len(rows), job, np.int64)
    return out


def merge_arrays(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    keys = sorted({k for p in parts for k in p})
    return {k: np.concatenate([p[k] for p in parts if k in p]) for k in keys}


class TraceStore:
    """The files of one traces directory."""

    def __init__(self, directory: str | Path) -> None:
        self.dir = Path(directory)
        self.pending = self.dir / "pending"

    def shard_paths(self) -> list[Path]:
        return sorted(self.dir.glob("shard_*.npz"))

    def pending_paths(self) -> list[Path]:
        return sorted(self.pending.glob("job_*.npz")) if self.pending.is_dir() else []

    def manifest(self) -> dict[str, Any] | None:
        path = self.dir / "manifest.json"
        if not path.is_file():
            return None
        try:
            return json.loads(path.read_text(encoding="utf-8"))
        except ValueError:
            raise TraceError(f"{path}: corrupt manifest") from None

    def write_manifest(self, manifest: dict[str, Any]) -> None:
        atomic_write(self.dir / "manifest.json",
                      json.dumps(manifest, indent=1).encode("utf-8"))

    def write_pending(self, arrays: dict[str, np.ndarray]) -> None:
        self.pending.mkdir(parents=True, exist_ok=True)
        _save_npz(self.pending / f"job_{int(arrays['jobs'][0]):08d}.npz", arrays)

    def finished(self) -> dict[str, np.ndarray]:
        """Every finished job's arrays (shards, then pending), deduplicated by job id."""
        parts = [_load_npz(p) for p in self.shard_paths()]
        seen: set[int] = set()
        for part in parts:
            seen.update(int(j) for j in part["jobs"])
        for path in self.pending_paths():
            part = _load_npz(path)
            if int(part["jobs"][0]) not in seen:  # else: already in a shard
                seen.add(int(part["jobs"][0]))
                parts.append(part)
        if not parts:
            return {"jobs": np.zeros(0, np.int64), "kept": np.zeros(0, bool)}
        merged = merge_arrays(parts)
        if len(np.unique(merged["jobs"])) != len(merged["jobs"]):
            raise TraceError(f"{self.dir}: a job id appears in two shards")
        return merged

    def consolidate(self) -> None:
        """Gather pending jobs into a new shard, then remove them."""
        paths = self.pending_paths()
        if not paths:
            return
        in_shards: set[int] = set()
        for p in self.shard_paths():
            in_shards.update(int(j) for j in _load_npz(p)["jobs"])
        parts = [a for a in (_load_npz(p) for p in paths) if int(a["jobs"][0]) not in in_shards]
        if parts:
            merged = merge_arrays(parts)
            _save_npz(self.dir / f"shard_{int(merged['jobs'].min()):08d}.npz", merged)
        for p in paths:
            p.unlink(missing_ok=True)


# --------------------------------------------------------------------------- workers

def _worker_setup(grammar: str, targets: str, size: int, mirror: bool,
                  guide: str | None = None) -> dict[str, Any]:
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(grammar)
    proposal = None
    if guide is not None:
        from ngpm_runtime.inference.guide import Guide

        proposal = Guide.load(guide, program)
    return {"program": program, "targets": load_targets(targets, size, mirror),
            "guide": proposal}


def _do_job(args: tuple[int, int, int, int]) -> tuple[dict[str, np.ndarray], float]:
    job, base_seed, particles, min_prims = args
    t0 = time.perf_counter()
    targets = pool.state()["targets"]
    ti, seed = job_spec(base_seed, job, len(targets))
    try:
        guide = pool.state().get("guide")
        extra = () if guide is None else (guide,)
        trace, n_prims = run_job(pool.state()["program"], targets[ti], seed, particles, *extra)
    except SMCFailed:  # every particle died: a property of the job, so it is dropped
        trace, n_prims = [], -1
    kept = n_prims >= min_prims
    return job_arrays(job, ti, seed, trace, n_prims, kept), time.perf_counter() - t0


def _config_key(cfg: TraceConfig, program: Program, targets: list[Any]) -> dict[str, Any]:
    key = {"grammar_hash": program.grammar_hash, "grammar": program.name,
           "targets": [t.name for t in targets], "particles": cfg.particles,
           "seed": cfg.seed, "mirror": cfg.mirror, "size": cfg.size,
           "min_primitives": cfg.min_primitives}
    if cfg.guide is not None:  # unguided directories keep the key they always had
        key["guide"] = _file_hash(cfg.guide)
    return key


def _file_hash(path: str | None) -> str | None:
    """sha256 of a file (the guide a traces directory was recorded with), None for None."""
    if path is None:
        return None
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _exit_on_sigterm() -> None:
    """Make SIGTERM unwind like Ctrl-C, so the pool's workers are stopped and the manifest of
    the finished jobs is written (the default SIGTERM handler skips all cleanup)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(128 + signum))


def generate_traces(cfg: TraceConfig, out_dir: str | Path, progress: bool = True,
                    on_job: Callable[[int], None] | None = None) -> dict[str, Any]:
    """Run trace jobs until `cfg.n` traces are kept (resuming); returns the manifest.

    Long because the serial and pooled paths share one try/finally that writes the finished
    jobs' manifest on any exit (done, Ctrl-C, SIGTERM)."""
    from ngpm_compiler.language.compile import load_grammar

    store = TraceStore(out_dir)
    store.dir.mkdir(parents=True, exist_ok=True)
    program = load_grammar(cfg.grammar)
    targets = load_targets(cfg.targets, cfg.size, cfg.mirror)
    key = _config_key(cfg, program, targets)
    old = store.manifest()
    if old is not None and old.get("key") != key:
        diff = sorted(k for k in key if old.get("key", {}).get(k) != key[k])
        raise TraceError(f"{store.dir}: holds traces of another configuration "
                         f"(differs in {', '.join(diff)}); use a new directory")
    store.consolidate()
    done = store.finished()
    done_ids = set(int(j) for j in done["jobs"])
    kept = int(done["kept"].sum())
    dropped = len(done_ids) - kept
    layouts = site_layouts(program, targets[0].mask)
    manifest: dict[str, Any] = {
        "format": TRACE_FORMAT, "key": key, "config": asdict(cfg),
        "grammar_hash": program.grammar_hash,
        "sites": [s.to_json() for s in program.sites],
        "layouts": {str(i): {g: [sl.start, sl.stop] for g, sl in lay.items()}
                    for i, lay in layouts.items()},
        "requested": cfg.n, "seconds": float(old.get("seconds", 0.0)) if old else 0.0,
    }
    t0 = time.perf_counter()
    bar = tqdm(total=cfg.n, initial=min(kept, cfg.n), desc="traces", unit="trace",
               disable=not progress)
    bar.set_postfix(dropped=dropped)
    since_shard = 0
    job_seconds: list[float] = list(old.get("job_seconds", [])) if old else []

    failed = int((done.get("n_prims", np.zeros(0)) < 0).sum())

    def finish(arrays: dict[str, np.ndarray], seconds: float) -> None:
        nonlocal kept, dropped, since_shard, failed
        store.write_pending(arrays)
        done_ids.add(int(arrays["jobs"][0]))
        job_seconds.append(seconds)
        if bool(arrays["kept"][0]):
            kept += 1
            bar.update(1)
        else:
            dropped += 1
            failed += int(arrays["n_prims"][0] < 0)
            bar.set_postfix(dropped=dropped)
        since_shard += 1
        if since_shard >= cfg.shard_size:
            store.consolidate()
            since_shard = 0
        if on_job:
            on_job(int(arrays["jobs"][0]))

    def next_ids() -> Any:
        j = 0
        while True:
            if j not in done_ids:
                yield j
            j += 1

    ids = next_ids()
    try:
        if cfg.workers <= 1:
            pool.setup_here(_worker_setup, cfg.grammar, cfg.targets, cfg.size, cfg.mirror,
                            cfg.guide)
            while kept < cfg.n:
                finish(*_do_job((next(ids), cfg.seed, cfg.particles, cfg.min_primitives)))
        else:
            _exit_on_sigterm()
            setup = (cfg.grammar, cfg.targets, cfg.size, cfg.mirror, cfg.guide)
            with pool.spawn_pool(cfg.workers, _worker_setup, setup) as workers:
                running: list[Any] = []
                while kept < cfg.n or running:
                    while kept + len(running) < cfg.n and len(running) < 2 * cfg.workers:
                        job = next(ids)
                        running.append(workers.apply_async(
                            _do_job, ((job, cfg.seed, cfg.particles, cfg.min_primitives),)))
                    ready = [r for r in running if r.ready()]
                    if not ready:
                        running[0].wait(0.05)
                        continue
                    for r in ready:
                        running.remove(r)
                        finish(*r.get())
    finally:
        bar.close()
        store.consolidate()
        manifest["seconds"] += time.perf_counter() - t0
        manifest["job_seconds"] = job_seconds
        manifest.update(kept=kept, dropped=dropped, failed=failed, jobs_done=len(done_ids),
                        shards=[p.name for p in store.shard_paths()])
        store.write_manifest(manifest)
    return manifest


# --------------------------------------------------------------------------- loading


@dataclass
class TraceSet:
    manifest: dict[str, Any]
    sites: list[Site]
    layouts: dict[int, dict[str, slice]]
    data: dict[int, SiteData]
    kept_jobs: np.ndarray
    dropped: int


def load_traces(directory: str | Path) -> TraceSet:
    """The kept traces of a traces directory, as training data per site."""
    store = TraceStore(directory)
    manifest = store.manifest()
    if manifest is None or manifest.get("format") != TRACE_FORMAT:
        raise TraceError(f"{store.dir}: not a traces directory (no manifest.json from "
                         "`ngpmc traces`)")
    done = store.finished()
    kept_jobs = np.sort(done["jobs"][done["kept"]])
    sites = [Site.from_json(s) for s in manifest["sites"]]
    layouts = {int(i): {g: slice(a, b) for g, (a, b) in lay.items()}
               for i, lay in manifest["layouts"].items()}
    data: dict[int, SiteData] = {}
    for site in sites:
        f = done.get(f"f_{site.index}")
        if f is None or len(f) == 0:
            continue
        v, j = done[f"v_{site.index}"], done[f"j_{site.index}"]
        args = f[:, prior_arg_columns(site, layouts[site.index])].astype(np.float64)
        data[site.index] = SiteData(f, v, args, j)
    return TraceSet(manifest, sites, layouts, data, kept_jobs,
                    int(len(done["jobs"]) - len(kept_jobs)))
