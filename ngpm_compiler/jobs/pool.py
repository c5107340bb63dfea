"""The one worker pool: spawned processes, each with state built once by a setup function.

Trace recording, the evaluation and model training all run their jobs through `spawn_pool`
(or, with one worker, in this process after `setup_here`); a job reads what the setup built
with `state()`.

Leaving the pool never hangs: `Pool.terminate()` first takes the task queue's lock, and a
worker killed while holding it (`timeout 60 ngpmc traces ...` sends SIGTERM to the whole
process group) never gives it back. So terminate() runs in a daemon thread; if it has not
finished in `grace` seconds, the workers are killed and the command goes on.

A worker whose setup fails (a guide of another grammar, a corrupt file) does not exit: a Pool
would start another in its place, forever. It keeps the error, and `state()` raises it in
every job it gets, so the driver's first result is that error.
"""

from __future__ import annotations

import multiprocessing as mp
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing.pool import Pool
from typing import Any

from ngpm_runtime.errors import NgpmError

Setup = Callable[..., dict[str, Any]]

_STATE: dict[str, Any] = {}
_FAILED: list[NgpmError] = []  # the setup's error, in a worker whose setup failed

GRACE_SECONDS = 3.0
MAX_RETRIES = 3  # runs of a job again after a worker process died running it (local or Ray)


def stop_pool(pool: Any, grace: float = GRACE_SECONDS) -> bool:
    """Terminate `pool`; True if its own terminate() finished, False if it had to be left."""
    stopper = threading.Thread(target=pool.terminate, name="pool-stop", daemon=True)
    stopper.start()
    stopper.join(grace)
    if not stopper.is_alive():
        return True
    for proc in list(getattr(pool, "_pool", None) or []):  # the worker processes
        try:
            proc.kill()
            proc.join(1.0)
        except (OSError, ValueError, AttributeError):
            pass
    stopper.join(1.0)
    return not stopper.is_alive()


def worker_pids(procs: Pool) -> set[int]:
    """The process ids of a pool's workers (a Pool starts a new one when one dies)."""
    return {p.pid for p in list(getattr(procs, "_pool", None) or []) if p.pid is not None}


def state() -> dict[str, Any]:
    """What this process's setup built (empty before `setup_here`); in a pool worker whose
    setup failed, raises the setup's error instead."""
    if _FAILED:
        raise _FAILED[0].with_traceback(None)
    return _STATE


def setup_here(setup: Setup, *args: Any) -> dict[str, Any]:
    """Run `setup(*args)` in this process and keep its result as the worker state."""
    _STATE.clear()
    _FAILED.clear()
    _STATE.update(setup(*args))
    return _STATE


def _setup_worker(setup: Setup, *args: Any) -> None:
    """A pool worker's initializer: `setup_here`, keeping a failure for `state()` to raise
    (as one line: an error that is not an NgpmError is named with its type)."""
    try:
        setup_here(setup, *args)
    except Exception as err:
        if not isinstance(err, NgpmError):
            err = NgpmError(f"a worker process could not start: {type(err).__name__}: {err}")
        _FAILED[:] = [err]


@contextmanager
def spawn_pool(
    workers: int,
    setup: Setup | None = None,
    args: tuple[Any, ...] = (),
    grace: float = GRACE_SECONDS,
) -> Iterator[Pool]:
    """`with spawn_pool(...) as procs:` a pool of `workers` spawned processes, each running
    `setup(*args)` once when given; stopped on the way out without ever hanging."""
    ctx = mp.get_context("spawn")
    if setup is None:
        procs = ctx.Pool(workers)
    else:
        procs = ctx.Pool(workers, initializer=_setup_worker, initargs=(setup, *args))
    try:
        yield procs
    finally:
        stop_pool(procs, grace)
