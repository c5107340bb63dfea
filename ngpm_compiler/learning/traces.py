"""Training traces: SMC on dataset targets, keep the best particle's trace.

SMC proposes from the grammar's prior (the paper) or, with `TraceConfig.guide`, from a
trained guide (expert iteration): guided SMC weighs each particle by prior / proposal, so
its particles are weighted samples of the same posterior and the kept best particle is a
trace of the same kind, only found with far fewer particles.

Job `i` is a pure function of (grammar, base seed, i): its target and SMC seed come from
`job_spec(base_seed, i, n_targets)`. Jobs run on a backend (`jobs/backends.py`: worker processes
here, or Ray tasks on a cluster) that gets the grammar's text and the targets, never paths;
the driver (this process) writes every finished job at once to `pending/job_<i>.npz`
(atomic), and gathers the jobs of each finished block of `shard_size` consecutive ids into a
shard `shard_<first>.npz` (the last, partial block when the run is complete). A rerun on the
same directory skips finished job ids, so an interrupted run loses no finished trace and
never repeats one; the driver ignores a second result for a written job. Shards are the same
bytes whatever backend ran the jobs, in whatever order they finished, however often the run
was interrupted (with one shard size).

Shard / pending npz arrays: `jobs, kept, n_prims, target, seed` (one entry per job; n_prims
is -1 when SMC failed: every particle died, so the job is dropped) and per
visited site `i`: `f_<i>` (m, n_f) float32 features, `v_<i>` (m,) values, `j_<i>` (m,) job ids.
`manifest.json` holds the configuration (checked on resume), site table, feature layouts and
counts; it is written at the start and after every shard, so it matches the shards on disk
even when a write fails. Every file is checked field by field when read (`shards.py`). Job
ids are handed out in increasing order and only while `kept + running < n`, so the finished
set is the shortest prefix of job ids holding `n` kept traces, however often the run is
interrupted.
"""

from __future__ import annotations

import contextlib
import io
import json
import signal
import sys
import threading
import time
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from ngpm_runtime.errors import SMCFailed
from ngpm_runtime.files import atomic_write
from ngpm_runtime.program import Program, Site

from ngpm_compiler.jobs import backends, pool
from ngpm_compiler.jobs.driver import drive
from ngpm_compiler.learning.shards import (
    ShardError,
    TraceError,
    check_manifest,
    check_shard,
    layout_widths,
    read_npz,
)
from ngpm_compiler.progress import Progress

TRACE_FORMAT = "ngpm-traces/1"
MIN_PRIMITIVES = 10  # the paper's code dropped shorter traces
# A run stops when this many jobs in a row are dropped: the grammar (nearly) never draws
# enough, and would otherwise run forever. At a drop rate of 50% it happens once in 10**15 jobs.
MAX_DROPPED_IN_A_ROW = 50


@dataclass
class SiteData:
    """Every recorded visit of one site: raw features, chosen values, prior args, job ids."""

    features: np.ndarray  # (m, n_f) float32
    values: np.ndarray  # (m,) float64
    prior_args: np.ndarray  # (m, n_args) float64
    jobs: np.ndarray  # (m,) int64: the trace each row belongs to


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
    max_modules: int | None = None  # the "max modules" cap (None: the grammar's or default)
    backend: str = "local"  # backends.BACKENDS: "local" (processes) or "ray"
    ray_address: str | None = None  # a Ray cluster (None: a local Ray instance)
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


def run_job(program: Program, target: Any, seed: int, particles: int, guide: Any = None,
            max_modules: int | None = None) -> tuple[list[tuple[int, np.ndarray, float]], int]:
    """SMC (guided by `guide`, else unguided) on one target; the best particle's trace and
    primitive count.

    The run records values only; the best particle alone is then replayed with its values
    to compute its features (the same rows a run with features for every particle gives)."""
    from ngpm_runtime.errors import ProgramError
    from ngpm_runtime.grow import grow
    from ngpm_runtime.inference.smc import TraceRecording, replay

    start = target.start_pose(program.viewport)
    best = grow(program, target, guide, particles, seed, trace=TraceRecording.VALUES,
                max_modules=max_modules).smc.best
    values = [(s, v) for s, _, v in best.trace or []]
    again = replay(program, values, start=start, canvas_size=target.size,
                   target_mask=target.mask, max_modules=max_modules)
    if again.primitives != best.primitives:
        raise ProgramError(f"program {program.name}: replaying the best particle's values "
                           "drew other primitives (generated code is not pure)")
    return list(again.trace or []), len(best.primitives)


def site_layouts(program: Program, target_mask: np.ndarray | None) -> dict[int, dict[str, slice]]:
    """FeatureMaker.layout for every site (traces record the context group too)."""
    from ngpm_runtime.image.features import FeatureMaker

    fm = FeatureMaker(program, program.viewport, target_mask, context=True)
    return {s.index: fm.layout(s) for s in program.sites}


def prior_arg_columns(site: Site, layout: dict[str, slice]) -> slice:
    """Columns of the prior arguments: the last `n_args` of the local group (section 6)."""
    stop = layout["local"].stop
    return slice(stop - site.n_args(), stop)


# --------------------------------------------------------------------------- files


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """np.savez, but the same arrays give the same bytes (no time stamps in the zip)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for key, arr in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            with zf.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(arr), allow_pickle=False)
    atomic_write(path, buf.getvalue())


def _load_npz(path: Path, widths: dict[int, int] | None = None) -> dict[str, np.ndarray]:
    """A shard's or pending job's arrays, checked (`shards.check_shard`)."""
    arrays = read_npz(path)
    check_shard(path, arrays, widths)
    return arrays


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
    """The files of one traces directory; with `widths` (site index -> feature columns),
    shards whose sites or feature widths differ are refused."""

    def __init__(self, directory: str | Path, widths: dict[int, int] | None = None) -> None:
        self.dir = Path(directory)
        self.pending = self.dir / "pending"
        self.widths = widths

    def shard_paths(self) -> list[Path]:
        return sorted(self.dir.glob("shard_*.npz"))

    def pending_paths(self) -> list[Path]:
        return sorted(self.pending.glob("job_*.npz")) if self.pending.is_dir() else []

    def manifest(self) -> dict[str, Any] | None:
        """manifest.json, checked (`shards.check_manifest`); None when there is none."""
        path = self.dir / "manifest.json"
        if not path.is_file():
            return None
        try:
            manifest = json.loads(path.read_text(encoding="utf-8"))
        except ValueError:
            raise TraceError(f"{path}: corrupt manifest (not JSON)") from None
        check_manifest(path, manifest)
        return manifest

    def write_manifest(self, manifest: dict[str, Any]) -> None:
        atomic_write(self.dir / "manifest.json",
                      json.dumps(manifest, indent=1).encode("utf-8"))

    def write_pending(self, arrays: dict[str, np.ndarray]) -> None:
        self.pending.mkdir(parents=True, exist_ok=True)
        save_npz(self.pending / f"job_{int(arrays['jobs'][0]):08d}.npz", arrays)

    def finished(self, unreadable: list[str] | None = None) -> dict[str, np.ndarray]:
        """Every finished job's arrays (shards, then pending), deduplicated by job id.
        With a list `unreadable`, shards that cannot be read or are malformed are skipped
        and named there (with the reason)."""
        parts = []
        where: dict[int, str] = {}  # job id -> the shard holding it
        for path in self.shard_paths():
            try:
                part = _load_npz(path, self.widths)
            except ShardError as err:
                if unreadable is None:
                    raise
                unreadable.append(f"{path.name} ({err.reason})")
                continue
            for j in part["jobs"].tolist():
                if j in where:
                    raise TraceError(f"{self.dir}: job {j} is in two shards, {where[j]} and "
                                     f"{path.name}; remove one of them")
                where[j] = path.name
            parts.append(part)
        for path in self.pending_paths():
            part = _load_npz(path, self.widths)
            if len(part["jobs"]) != 1 or f"job_{int(part['jobs'][0]):08d}.npz" != path.name:
                raise ShardError(path, "'jobs' does not hold the one job the file is named for")
            if int(part["jobs"][0]) not in where:  # else: already in a shard
                where[int(part["jobs"][0])] = path.name
                parts.append(part)
        if not parts:
            return {"jobs": np.zeros(0, np.int64), "kept": np.zeros(0, bool)}
        return merge_arrays(parts)

    def consolidate(self, done: set[int] | None = None, block: int = 1) -> None:
        """Gather pending jobs into new shards, then remove them: with `done` (every finished
        job id), one shard per block of `block` consecutive job ids that are all done, and
        the other pending jobs stay pending; without, all pending jobs into one shard."""
        groups: dict[int, list[Path]] = {}
        for p in self.pending_paths():
            job = int(p.stem.partition("_")[2])
            groups.setdefault(job // block if done is not None else 0, []).append(p)
        if done is not None:
            groups = {b: ps for b, ps in groups.items()
                      if all(j in done for j in range(b * block, (b + 1) * block))}
        if not groups:
            return
        in_shards: set[int] = set()
        for p in self.shard_paths():
            in_shards.update(int(j) for j in _load_npz(p)["jobs"])
        for paths in groups.values():
            parts = [a for a in (_load_npz(p) for p in paths)
                     if int(a["jobs"][0]) not in in_shards]
            if parts:
                merged = merge_arrays(parts)
                save_npz(self.dir / f"shard_{int(merged['jobs'].min()):08d}.npz", merged)
            for p in paths:
                p.unlink(missing_ok=True)


# --------------------------------------------------------------------------- workers

def _worker_setup(grammar: str, text: str, targets: list[Any],
                  guide: str | bytes | None = None) -> dict[str, Any]:
    """A worker's state from the grammar file's name and text, the targets and the guide
    (its path, or its file's bytes for workers on other machines), so a worker on another
    machine reads no file."""
    import os

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(grammar, text)
    proposal = None if guide is None else backends.load_guide(guide, program)
    return {"program": program, "targets": targets, "guide": proposal}


def _do_job(args: tuple[int, ...]) -> tuple[dict[str, np.ndarray], float]:
    job, base_seed, particles, min_prims = args[:4]
    max_modules = args[4] if len(args) > 4 else None
    t0 = time.perf_counter()
    targets = pool.state()["targets"]
    ti, seed = job_spec(base_seed, job, len(targets))
    try:
        trace, n_prims = run_job(pool.state()["program"], targets[ti], seed, particles,
                                 guide=pool.state().get("guide"), max_modules=max_modules)
    except SMCFailed:  # every particle died: a property of the job, so it is dropped
        trace, n_prims = [], -1
    kept = n_prims >= min_prims
    return job_arrays(job, ti, seed, trace, n_prims, kept), time.perf_counter() - t0


def _config_key(cfg: TraceConfig, program: Program, targets: list[Any]) -> dict[str, Any]:
    return {"grammar_hash": program.grammar_hash, "grammar": program.name,
            "targets": [t.name for t in targets], "particles": cfg.particles,
            "seed": cfg.seed, "mirror": cfg.mirror, "size": cfg.size,
            "min_primitives": cfg.min_primitives, "max_modules": cfg.max_modules,
            "guide": _file_hash(cfg.guide)}


def _file_hash(path: str | None) -> str | None:
    """sha256 of a file (the guide a traces directory was recorded with), None for None."""
    if path is None:
        return None
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


_STOP: list[int] = []  # the signal that asked this run to stop


def _exit_on_sigterm() -> None:
    """Make SIGTERM unwind like Ctrl-C, so the pool's workers are stopped and the manifest of
    the finished jobs is written (the default SIGTERM handler skips all cleanup)."""
    _STOP.clear()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _note_sigterm)


def _note_sigterm(signum: int, frame: Any) -> None:
    """Note the signal; the driver loop exits with 128 + signum at its next turn (within
    0.05 s). Raised here, inside a backend's wait, Ray would replace the exit with its own
    SystemExit(1). A second SIGTERM during the cleanup (writing the manifest) is ignored."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _STOP.append(signum)


def _exit_if_stopped() -> None:
    if _STOP:
        sys.exit(128 + _STOP[0])


def _check_module_cap(cfg: TraceConfig, program: Program, target: Any) -> None:
    """After a few dropped jobs in a row: TraceError if a prior sample stops at the
    "max modules" cap before drawing enough (the grammar expands without drawing), so the
    run stops at once with the reason instead of after MAX_DROPPED_IN_A_ROW slow jobs."""
    from ngpm_runtime.inference.smc import forward, module_cap

    sample = forward(program, seed=cfg.seed, start=target.start_pose(program.viewport),
                     max_modules=cfg.max_modules)
    if sample.limit == "max modules" and len(sample.primitives) < cfg.min_primitives:
        raise TraceError(
            f"{cfg.grammar}: jobs are dropped because samples stop at the 'max modules' cap "
            f"({module_cap(program, cfg.max_modules)} modules expanded in one step without "
            f"drawing) with {len(sample.primitives)} primitives; the grammar expands without "
            "drawing (e.g. `A --> A A`): make it draw, lower its 'derivation length:', or "
            "raise the cap (--max-modules)")


def generate_traces(cfg: TraceConfig, out_dir: str | Path, progress: bool = True,
                    on_job: Callable[[int], None] | None = None) -> dict[str, Any]:
    """Run trace jobs until `cfg.n` traces are kept (resuming); returns the manifest.

    Long because one try/finally around the backend's driver loop writes the finished
    jobs' shards and manifest on any exit (done, Ctrl-C, SIGTERM, a failed job). The manifest
    is also written at the start and after every shard, so it always matches the shards on
    disk, even when a later write fails (disk full)."""
    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(cfg.grammar)
    if program.viewport is None:
        raise TraceError(f"{cfg.grammar}: the grammar has no 'viewport:' line; traces draw "
                         "into target images, so add one (e.g. 'viewport: -12 12 -22 2')")
    if cfg.guide is not None:  # a guide that does not load or fit: one error, before workers
        backends.load_guide(cfg.guide, program)
    targets = load_targets(cfg.targets, cfg.size, cfg.mirror)
    layouts = site_layouts(program, targets[0].mask)
    store = TraceStore(out_dir, layout_widths(layouts))
    store.dir.mkdir(parents=True, exist_ok=True)
    key = _config_key(cfg, program, targets)
    old = store.manifest()
    if old is not None and old.get("key") != key:
        theirs = old.get("key", {})
        diff = sorted(k for k in {*key, *theirs}  # a key missing on one side differs too
                      if (k in key, key.get(k)) != (k in theirs, theirs.get(k)))
        raise TraceError(f"{store.dir}: holds traces of another configuration "
                         f"(differs in {', '.join(diff)}); use a new directory")
    done = store.finished()
    done_ids = set(int(j) for j in done["jobs"])
    store.consolidate(done_ids, cfg.shard_size)
    kept = int(done["kept"].sum())
    dropped = len(done_ids) - kept
    manifest: dict[str, Any] = {
        "format": TRACE_FORMAT, "key": key, "config": asdict(cfg),
        "grammar_hash": program.grammar_hash,
        "sites": [s.to_json() for s in program.sites],
        "layouts": {str(i): {g: [sl.start, sl.stop] for g, sl in lay.items()}
                    for i, lay in layouts.items()},
        "requested": cfg.n,
    }
    seconds_before = float(old.get("seconds", 0.0)) if old else 0.0
    t0 = time.perf_counter()
    bar = Progress("traces", cfg.n, "trace", initial=min(kept, cfg.n), enabled=progress)
    bar.set_postfix(dropped=dropped)
    job_seconds: list[float] = list(old.get("job_seconds", [])) if old else []

    failed = int((done.get("n_prims", np.zeros(0)) < 0).sum())
    in_a_row = 0  # jobs dropped since the last kept one (this run)

    def save() -> None:
        manifest.update(seconds=seconds_before + time.perf_counter() - t0,
                        job_seconds=job_seconds, kept=kept, dropped=dropped, failed=failed,
                        jobs_done=len(done_ids), shards=[p.name for p in store.shard_paths()])
        store.write_manifest(manifest)

    save()

    def finish(arrays: dict[str, np.ndarray], seconds: float) -> None:
        nonlocal kept, dropped, failed, in_a_row
        job = int(arrays["jobs"][0])
        store.write_pending(arrays)
        done_ids.add(job)
        job_seconds.append(seconds)
        if bool(arrays["kept"][0]):
            kept += 1
            in_a_row = 0
            bar.update()
        else:
            dropped += 1
            in_a_row += 1
            failed += int(arrays["n_prims"][0] < 0)
            bar.set_postfix(dropped=dropped)
            if in_a_row == 5:
                _check_module_cap(cfg, program, targets[0])
            if in_a_row >= MAX_DROPPED_IN_A_ROW:
                raise TraceError(
                    f"{cfg.grammar}: stopped after {in_a_row} jobs in a row were dropped: "
                    f"their best particles drew fewer than {cfg.min_primitives} primitives "
                    "(or none survived); make the grammar draw more (a longer axiom or "
                    "derivation; try `ngpmc sample`) or raise its 'max modules:' cap if "
                    "`ngpmc sample` reports that limit")
        first = job - job % cfg.shard_size
        if all(j in done_ids for j in range(first, first + cfg.shard_size)):
            store.consolidate(done_ids, cfg.shard_size)  # its block is complete
            save()
        if on_job:
            on_job(job)

    def todo() -> Iterator[tuple[int, tuple[int, ...]]]:
        j = 0
        while True:
            if j not in done_ids:
                yield j, (j, cfg.seed, cfg.particles, cfg.min_primitives, cfg.max_modules)
            j += 1

    text = Path(cfg.grammar).read_text(encoding="utf-8")
    guide = backends.ship_file(cfg.guide, cfg.backend)
    jobs = backends.make_backend(cfg.backend, cfg.workers, _worker_setup,
                                 (cfg.grammar, text, targets, guide), cfg.ray_address)
    complete = False
    try:
        with jobs if kept < cfg.n else contextlib.nullcontext():
            if jobs.separate_processes:
                _exit_on_sigterm()  # after the backend started (ray.init sets its own)
            drive(jobs, _do_job, todo(), lambda _, result: finish(*result),
                  room=lambda running: kept + running < cfg.n, between=_exit_if_stopped)
            complete = True
    finally:
        bar.close()
        _close_run(store, done_ids, cfg.shard_size, complete, save)
    return manifest


def _close_run(store: TraceStore, done: set[int], block: int, complete: bool,
               save: Callable[[], None]) -> None:
    """Gather the finished blocks (all pending jobs when the run is `complete`) into shards,
    then `save` the manifest; also when a shard cannot be written (disk full): the manifest
    then lists the shards that are there, and the other jobs stay pending for a rerun."""
    try:
        if complete:
            store.consolidate()  # the last, partial block
        else:
            store.consolidate(done, block)
    except OSError:
        with contextlib.suppress(OSError):  # the shard's error is the one to report
            save()
        raise
    save()


# --------------------------------------------------------------------------- loading


@dataclass
class TraceSet:
    manifest: dict[str, Any]
    sites: list[Site]
    layouts: dict[int, dict[str, slice]]
    data: dict[int, SiteData]
    kept_jobs: np.ndarray
    dropped: int


def load_traces(directory: str | Path, allow_missing: bool = False) -> TraceSet:
    """The kept traces of a traces directory, as training data per site. TraceError when
    shards that the manifest lists are missing or unreadable, unless `allow_missing`."""
    store = TraceStore(directory)
    manifest = store.manifest()
    if manifest is None or manifest.get("format") != TRACE_FORMAT:
        raise TraceError(f"{store.dir}: not a traces directory (no manifest.json from "
                         "`ngpmc traces`)")
    sites = [Site.from_json(s) for s in manifest["sites"]]
    layouts = {int(i): {g: slice(a, b) for g, (a, b) in lay.items()}
               for i, lay in manifest["layouts"].items()}
    store.widths = layout_widths(layouts)
    unreadable: list[str] = []
    done = store.finished(unreadable)
    kept_jobs = np.sort(done["jobs"][done["kept"]])
    _check_complete(store, manifest, unreadable, len(kept_jobs), allow_missing)
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


def _check_complete(store: TraceStore, manifest: dict[str, Any], unreadable: list[str],
                    kept: int, allow_missing: bool) -> None:
    """TraceError naming the shards the manifest lists that are gone or unreadable (and the
    kept traces that are missing), unless `allow_missing`; then only a warning on stderr."""
    present = {p.name for p in store.shard_paths()}
    gone = [name for name in manifest.get("shards", []) if name not in present]
    lost = max(0, int(manifest.get("kept", kept)) - kept)
    if not (gone or unreadable or lost):
        return
    problems = []
    if gone:
        problems.append(f"missing {', '.join(gone)}")
    if unreadable:
        problems.append(f"unreadable {', '.join(unreadable)}")
    text = (f"{store.dir}: {'; '.join(problems) or 'files missing'}: {kept} of the "
            f"{kept + lost} kept traces are there")
    if allow_missing:
        print(f"ngpmc: warning: {text}; training on those (--allow-missing)", file=sys.stderr)
        return
    raise TraceError(f"{text}; restore the files, run `ngpmc traces` again with the same "
                     "options to redo the lost jobs (after removing unreadable shards), or "
                     "pass --allow-missing to train on what is there")
