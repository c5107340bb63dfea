"""Runs of `ngpmc serve`: one per client address and at most `Limits.max_runs` at once
(`RunSlots`), each in a worker thread that stops at its time limit or when its client goes
away (`RunCheck`, checked at every SMC step), and the decode slots that bound the pictures
read at once."""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from ngpm_runtime.errors import NgpmError
from ngpm_runtime.grow import GrowResult
from ngpm_runtime.inference.smc import SMCObserver, SMCState
from starlette.requests import Request

from ngpm_compiler.web.sse import Emit, FrameStream, done_event, target_event
from ngpm_compiler.web.validate import ApiError, Job

log = logging.getLogger("ngpmc.serve")


class RunStopped(Exception):
    """Raised inside SMC (by the RunCheck observer) to end a run early."""


@dataclass
class Run:
    client: str
    timeout_s: float
    cancel: threading.Event = field(default_factory=threading.Event)
    started: float = field(default_factory=time.monotonic)

    def check(self) -> None:
        if self.cancel.is_set():
            raise RunStopped("the run was stopped")
        if time.monotonic() - self.started > self.timeout_s:
            raise RunStopped(
                f"the run took longer than the {self.timeout_s:g} s time limit and "
                "was stopped; try fewer particles"
            )


class RunSlots:
    """One run per client address, at most `max_runs` runs at once."""

    def __init__(self, max_runs: int, timeout_s: float) -> None:
        self.max_runs = max_runs
        self.timeout_s = timeout_s
        self._lock = threading.Lock()
        self._active: dict[str, Run] = {}

    def acquire(self, client: str) -> Run:
        with self._lock:
            if client in self._active:
                raise ApiError(
                    409,
                    f"a run from your address ({client}) is still going: wait "
                    "for it to finish or stop it first",
                )
            if len(self._active) >= self.max_runs:
                raise ApiError(
                    503,
                    f"the server is busy with {len(self._active)} runs; try again in a moment",
                    {"Retry-After": "2"},
                )
            run = Run(client, self.timeout_s)
            self._active[client] = run
            return run

    def release(self, run: Run) -> None:
        with self._lock:
            if self._active.get(run.client) is run:
                del self._active[run.client]

    def active(self) -> int:
        with self._lock:
            return len(self._active)


def client_id(request: Request) -> str:
    """Whose run it is: the peer's address. Not a cookie or a header: those are the
    client's own word, and a client that changed them at will could take every slot."""
    return request.client.host if request.client else "unknown"


async def in_decode_slot(request: Request, work: Callable[..., Any], *args: Any) -> Any:
    """`work(*args)` (which decodes a picture) in a worker thread, holding one of the
    `max_runs` decode slots, so that many uploads at once cannot take the memory; 503 when
    every slot is taken. The thread itself gives the slot back, even if the request is
    abandoned meanwhile."""
    slots: threading.BoundedSemaphore = request.app.state.decode_slots
    if not slots.acquire(blocking=False):
        raise ApiError(
            503,
            "the server is busy reading other pictures; try again in a moment",
            {"Retry-After": "2"},
        )

    def held() -> Any:
        try:
            return work(*args)
        finally:
            slots.release()

    return await asyncio.to_thread(held)


class RunCheck(SMCObserver):
    """Stops the run (RunStopped) after a step once it is cancelled or out of time."""

    def __init__(self, run: Run) -> None:
        self.run = run

    def step_done(self, state: SMCState) -> None:
        if state.drawn:
            self.run.check()


def grow_job(job: Job, observers: Sequence[SMCObserver] = ()) -> GrowResult:
    """The one call of the runtime's grow() for a job."""
    from ngpm_runtime import grow

    return grow(
        job.grammar.program,
        job.target,
        job.guide.guide if job.guide else None,
        job.particles,
        job.seed,
        "shape",
        observers=observers,
    )


def run_job(job: Job, run: Run, slots: RunSlots, emit: Emit) -> None:
    """The worker thread: target, frames, then done or error (after the slot is free)."""
    final: tuple[str, dict[str, Any]]
    try:
        emit("target", target_event(job))
        frames = FrameStream(emit)
        res = grow_job(job, (RunCheck(run), frames))
        final = ("done", done_event(job, res, frames.steps))
    except RunStopped as err:
        final = ("error", {"error": str(err)})
    except NgpmError as err:
        final = ("error", {"error": str(err)})
    except Exception as err:  # never kill the server; the log has the traceback
        log.exception("run failed")
        final = (
            "error",
            {"error": f"internal error ({type(err).__name__}); the server log has details"},
        )
    finally:
        slots.release(run)
    emit(*final)
