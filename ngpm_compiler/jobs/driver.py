"""The one driver loop: keeps a started backend busy with jobs and hands each result back
once. Trace recording (`learning/traces.py`) and evaluation runs (`evaluation/runs.py`) both
run their jobs through `drive`."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

from ngpm_compiler.jobs.backends import Backend, Job

POLL_SECONDS = 0.05  # how long one poll waits for a result


def drive(
    jobs: Backend,
    fn: Job,
    todo: Iterator[tuple[int, Any]],
    on_result: Callable[[int, Any], None],
    room: Callable[[int], bool] = lambda running: True,
    between: Callable[[], None] | None = None,
) -> None:
    """Run `fn(arg)` for each (key, arg) of `todo` on `jobs`, keeping up to `jobs.capacity`
    submitted while `room(jobs running)` holds. `on_result(key, result)` gets each key once
    (a retried job's second result is dropped); `between()` runs after every poll. Returns
    when nothing runs and `todo` is used up or `room(0)` is false."""
    handed: set[int] = set()
    used_up = False
    while True:
        while not used_up and jobs.running() < jobs.capacity and room(jobs.running()):
            nxt = next(todo, None)
            if nxt is None:
                used_up = True
            else:
                jobs.submit(nxt[0], fn, nxt[1])
        if not jobs.running() and (used_up or not room(0)):
            return
        for key, result in jobs.results(POLL_SECONDS):
            if key not in handed:
                handed.add(key)
                on_result(key, result)
        if between is not None:
            between()
