"""Training traces: SMC on dataset targets, keep the best particle's trace (`generate_traces`,
the driver; a job: trace_jobs.py, in a worker: trace_workers.py, the files: trace_store.py,
loading them for training: trace_data.py).

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

`manifest.json` holds the configuration (checked on resume), site table, feature layouts and
counts; it is written at the start and after every shard, so it matches the shards on disk
even when a write fails. Every file is checked field by field when read (`shards.py`). Job
ids are handed out in increasing order and only while `kept + running < n`, so the finished
set is the shortest prefix of job ids holding `n` kept traces, however often the run is
interrupted.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, cast

import numpy as np
from ngpm_runtime.program import Program

from ngpm_compiler.jobs import backends
from ngpm_compiler.jobs.driver import drive
from ngpm_compiler.learning.shards import TraceError, layout_widths
from ngpm_compiler.learning.trace_jobs import (
    MIN_PRIMITIVES,
    check_frame,
    load_targets,
    site_layouts,
    start_of,
)
from ngpm_compiler.learning.trace_store import TRACE_FORMAT, TraceStore
from ngpm_compiler.learning.trace_workers import JobArgs, do_job, worker_setup
from ngpm_compiler.progress import Progress

if TYPE_CHECKING:
    from ngpm_runtime.image.targets import Target

# A run stops when this many jobs in a row are dropped: the grammar (nearly) never draws
# enough, and would otherwise run forever. At a drop rate of 50% it happens once in 10**15 jobs.
MAX_DROPPED_IN_A_ROW = 50


@dataclass
class TraceConfig:
    grammar: str  # .lsys source or a generated *_sampler.py
    targets: str  # dataset directory ("" under the circuit likelihood: no targets)
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
    likelihood: str = "shape"  # or "circuit": every job grows into grow.circuit_target
    sigma: float | None = None  # a 3D grammar's voxel likelihood sigma (None: 0.02)
    # ground-truth traces: each job's target is the envelope of a forward sample and its
    # trace that sample's own values (trace_jobs.run_own_job); no SMC, no targets
    own_samples: bool = False


def _config_key(
    cfg: TraceConfig, program: Program, targets: list[Target], window: str | None = None
) -> dict[str, Any]:
    """What a traces directory's jobs depend on; a rerun with another key is refused."""
    return {
        "grammar_hash": program.grammar_hash,
        "grammar": program.name,
        "targets": [t.name for t in targets],
        "particles": cfg.particles,
        "seed": cfg.seed,
        "mirror": cfg.mirror,
        "size": cfg.size,
        "min_primitives": cfg.min_primitives,
        "max_modules": cfg.max_modules,
        "guide": _file_hash(cfg.guide),
        # only under the circuit likelihood, so shape traces recorded before it was an
        # option still resume
        **({"likelihood": cfg.likelihood} if cfg.likelihood != "shape" else {}),
        **({"sigma": cfg.sigma} if cfg.sigma is not None else {}),
        # a 3D grammar's window, once windows turned with the turtle (volume/features.py)
        **({"window": window} if window == "frame" else {}),
        **({"own_samples": True} if cfg.own_samples else {}),
    }


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


def _note_sigterm(signum: int, frame: FrameType | None) -> None:
    """Note the signal; the driver loop exits with 128 + signum at its next turn (within
    0.05 s). Raised here, inside a backend's wait, Ray would replace the exit with its own
    SystemExit(1). A second SIGTERM during the cleanup (writing the manifest) is ignored."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _STOP.append(signum)


def _exit_if_stopped() -> None:
    if _STOP:
        sys.exit(128 + _STOP[0])


def _check_module_cap(cfg: TraceConfig, program: Program, target: Target) -> None:
    """After a few dropped jobs in a row: TraceError if a prior sample stops at the
    "max modules" cap before drawing enough (the grammar expands without drawing), so the
    run stops at once with the reason instead of after MAX_DROPPED_IN_A_ROW slow jobs."""
    from ngpm_runtime.inference.smc import forward, module_cap

    sample = forward(
        program,
        seed=cfg.seed,
        # a 3D start is (x, y, z, heading): forward hands it to SMCOptions as it is
        start=cast("tuple[float, float, float]", start_of(program, target)),
        max_modules=cfg.max_modules,
    )
    if sample.limit == "max modules" and len(sample.primitives) < cfg.min_primitives:
        raise TraceError(
            f"{cfg.grammar}: jobs are dropped because samples stop at the 'max modules' cap "
            f"({module_cap(program, cfg.max_modules)} modules expanded in one step without "
            f"drawing) with {len(sample.primitives)} primitives; the grammar expands without "
            "drawing (e.g. `A --> A A`): make it draw, lower its 'derivation length:', or "
            "raise the cap (--max-modules)"
        )


def trace_targets(cfg: TraceConfig, program: Program) -> list[Any]:
    """The targets jobs grow into: the dataset's, or under the circuit likelihood the one
    blank canvas `grow.circuit_target` (its start and size; TraceError given targets); none
    for ground-truth traces (`own_samples`: each job makes its own)."""
    if cfg.own_samples:
        if cfg.targets or cfg.mirror or cfg.guide or cfg.likelihood != "shape":
            raise TraceError(
                "ground-truth traces make their own targets (envelopes of the grammar's "
                "samples) and run no SMC: drop --targets, --mirror, --guide and --likelihood"
            )
        if program.dim == 3:
            raise TraceError(f"{cfg.grammar}: ground-truth traces are for 2D grammars")
        return []
    if cfg.likelihood == "shape":
        return load_targets(cfg.targets, cfg.size, cfg.mirror, program)
    from ngpm_runtime.grow import LIKELIHOODS, circuit_target

    if cfg.likelihood not in LIKELIHOODS:
        raise TraceError(f"unknown likelihood {cfg.likelihood!r}; choose shape or circuit")
    if program.dim == 3:
        raise TraceError(f"{cfg.grammar}: a 3D grammar records traces with the shape likelihood")
    if cfg.targets or cfg.mirror:
        raise TraceError(
            "the circuit likelihood has no targets: every trace starts at the bottom middle "
            "of the viewport, heading up (drop --targets and --mirror)"
        )
    return [circuit_target((cfg.size, cfg.size))]


def generate_traces(
    cfg: TraceConfig,
    out_dir: str | Path,
    progress: bool = True,
    on_job: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Run trace jobs until `cfg.n` traces are kept (resuming); returns the manifest.

    Long because one try/finally around the backend's driver loop writes the finished
    jobs' shards and manifest on any exit (done, Ctrl-C, SIGTERM, a failed job). The manifest
    is also written at the start and after every shard, so it always matches the shards on
    disk, even when a later write fails (disk full)."""
    from ngpm_compiler.language.compile import load_grammar

    program = load_grammar(cfg.grammar)
    check_frame(program, cfg.grammar)
    if cfg.sigma is not None and not (program.dim == 3 and cfg.sigma > 0):
        raise TraceError(
            f"--sigma {cfg.sigma}: a positive sigma of a 3D grammar's voxel likelihood "
            f"({cfg.grammar} is {program.dim}D)"
        )
    window = None  # a 3D teacher's window is the one its traces record
    if cfg.guide is not None:  # a guide that does not load or fit: one error, before workers
        window = backends.load_guide(cfg.guide, program).feature_window
    targets = trace_targets(cfg, program)
    if program.dim == 3 and window is None:
        from ngpm_runtime.volume.features import DEFAULT_WINDOW

        window = DEFAULT_WINDOW
    layouts = site_layouts(program, targets[0] if targets else None, window)
    store = TraceStore(out_dir, layout_widths(layouts))
    store.dir.mkdir(parents=True, exist_ok=True)
    key = _config_key(cfg, program, targets, window)
    old = store.manifest()
    if old is not None and old.get("key") != key:
        theirs = old.get("key", {})
        diff = sorted(
            k
            for k in {*key, *theirs}  # a key missing on one side differs too
            if (k in key, key.get(k)) != (k in theirs, theirs.get(k))
        )
        hint = ""
        if diff == ["min_primitives"]:
            hint = f" or --min-primitives {theirs['min_primitives']} to resume it"
        raise TraceError(
            f"{store.dir}: holds traces of another configuration "
            f"(differs in {', '.join(diff)}); use a new directory{hint}"
        )
    new_layouts = {
        str(i): {g: [sl.start, sl.stop] for g, sl in lay.items()} for i, lay in layouts.items()
    }
    if old is not None and old.get("layouts", new_layouts) != new_layouts:
        raise TraceError(
            f"{store.dir}: its traces' feature rows have another layout (recorded by an "
            f"older ngpm); use a new directory"
        )
    done = store.finished()
    done_ids = set(int(j) for j in done["jobs"])
    store.consolidate(done_ids, cfg.shard_size)
    kept = int(done["kept"].sum())
    dropped = len(done_ids) - kept
    manifest: dict[str, Any] = {
        "format": TRACE_FORMAT,
        "key": key,
        "config": asdict(cfg),
        "grammar_hash": program.grammar_hash,
        "sites": [s.to_json() for s in program.sites],
        "layouts": new_layouts,
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
        manifest.update(
            seconds=seconds_before + time.perf_counter() - t0,
            job_seconds=job_seconds,
            kept=kept,
            dropped=dropped,
            failed=failed,
            jobs_done=len(done_ids),
            shards=[p.name for p in store.shard_paths()],
        )
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
            if in_a_row == 5 and targets:
                _check_module_cap(cfg, program, targets[0])
            if in_a_row >= MAX_DROPPED_IN_A_ROW and cfg.own_samples:
                from ngpm_compiler.datasets.envelopes import MIN_INK

                raise TraceError(
                    f"{cfg.grammar}: stopped after {in_a_row} jobs in a row found no forward "
                    f"sample whose envelope covers {MIN_INK:.0%} of the canvas; fit the "
                    "viewport to what the grammar draws (`ngpmc check` proposes one)"
                )
            if in_a_row >= MAX_DROPPED_IN_A_ROW:
                raise TraceError(
                    f"{cfg.grammar}: stopped after {in_a_row} jobs in a row were dropped: "
                    f"their best particles drew fewer than {cfg.min_primitives} primitives "
                    "(or none survived); make the grammar draw more (a longer axiom or "
                    "derivation; try `ngpmc sample`) or raise its 'max modules:' cap if "
                    "`ngpmc sample` reports that limit"
                )
        first = job - job % cfg.shard_size
        if all(j in done_ids for j in range(first, first + cfg.shard_size)):
            store.consolidate(done_ids, cfg.shard_size)  # its block is complete
            save()
        if on_job:
            on_job(job)

    def todo() -> Iterator[tuple[int, JobArgs]]:
        j = 0
        while True:
            if j not in done_ids:
                yield j, (j, cfg.seed, cfg.particles, cfg.min_primitives, cfg.max_modules)
            j += 1

    text = Path(cfg.grammar).read_text(encoding="utf-8")
    guide = backends.ship_file(cfg.guide, cfg.backend)
    jobs = backends.make_backend(
        cfg.backend,
        cfg.workers,
        worker_setup,
        (
            cfg.grammar,
            text,
            targets,
            guide,
            cfg.likelihood,
            cfg.sigma,
            cfg.size if cfg.own_samples else 0,
        ),
        cfg.ray_address,
    )
    complete = False
    try:
        with jobs if kept < cfg.n else contextlib.nullcontext():
            if jobs.separate_processes:
                _exit_on_sigterm()  # after the backend started (ray.init sets its own)
            drive(
                jobs,
                do_job,
                todo(),
                lambda _, result: finish(*result),
                room=lambda running: kept + running < cfg.n,
                between=_exit_if_stopped,
            )
            complete = True
    finally:
        bar.close()
        _close_run(store, done_ids, cfg.shard_size, complete, save)
    return manifest


def _close_run(
    store: TraceStore, done: set[int], block: int, complete: bool, save: Callable[[], None]
) -> None:
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
