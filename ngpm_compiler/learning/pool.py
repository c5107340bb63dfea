"""The one worker pool: spawned processes, each with state built once by a setup function.

Trace recording, the evaluation and model training all run their jobs through `spawn_pool`
(or, with one worker, in this process after `setup_here`); a job reads what the setup built
with `state()`.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable
from multiprocessing.pool import Pool
from typing import Any

Setup = Callable[..., dict[str, Any]]

_STATE: dict[str, Any] = {}


def state() -> dict[str, Any]:
    """What this process's setup built (empty before `setup_here`)."""
    return _STATE


def setup_here(setup: Setup, *args: Any) -> dict[str, Any]:
    """Run `setup(*args)` in this process and keep its result as the worker state."""
    _STATE.clear()
    _STATE.update(setup(*args))
    return _STATE


def spawn_pool(workers: int, setup: Setup | None = None, args: tuple[Any, ...] = ()) -> Pool:
    """A pool of `workers` spawned processes; each runs `setup(*args)` once when given."""
    ctx = mp.get_context("spawn")
    if setup is None:
        return ctx.Pool(workers)
    return ctx.Pool(workers, initializer=setup_here, initargs=(setup, *args))
