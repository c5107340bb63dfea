"""Where jobs run: a `Backend` takes jobs from a driver and hands their results back, in any
order, as they finish.

A job is `fn(arg)` with `fn` a module-level function (so it pickles by reference) that reads
what the backend's setup built with `pool.state()`. The setup runs once per worker process
(`setup(*setup_args)`); its arguments are data, not paths, so that a worker on another
machine needs none of the driver's files. Backends never write anything: the driver does
(trace shards, CSV rows), so a job that runs twice (a retry after a worker crash) can never
be recorded twice.

- `InProcess`: one job at a time in this process (`--workers 1`).
- `LocalPool`: spawned worker processes on this machine (the default).
- `RayBackend` (`ray_backend.py`, needs the `cluster` extra): Ray tasks on a local Ray
  instance or on a cluster (`--backend ray [--ray-address ADDRESS]`).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol

from ngpm_runtime.errors import NgpmError

from ngpm_compiler.jobs import pool

if TYPE_CHECKING:  # onnxruntime loads only in the workers that use a guide
    from ngpm_runtime.inference.guide import Guide
    from ngpm_runtime.program import Program

BACKENDS = ("local", "ray")
Job = Callable[[Any], Any]


class Backend(Protocol):
    """A context manager (entering starts the workers, leaving cancels what still runs and
    stops them) that runs submitted jobs."""

    capacity: int  # jobs worth keeping submitted at once (about 2 per worker)
    separate_processes: bool  # jobs run outside this process (SIGTERM must stop them)

    def __enter__(self) -> Backend: ...

    def __exit__(
        self, kind: type[BaseException] | None, err: BaseException | None, tb: TracebackType | None
    ) -> None: ...

    def submit(self, key: int, fn: Job, arg: Any) -> None:
        """Queue `fn(arg)`; its result comes back from `results` under `key`."""

    def running(self) -> int:
        """Jobs submitted whose results have not been handed back yet."""

    def results(self, timeout: float) -> list[tuple[int, Any]]:
        """(key, result) of jobs finished since the last call, waiting up to `timeout`
        seconds for the first; a job's exception is raised here."""


class InProcess:
    """Jobs run here, one at a time, when their results are asked for."""

    separate_processes = False
    capacity = 1

    def __init__(self, setup: pool.Setup, setup_args: tuple[Any, ...]) -> None:
        self._setup = (setup, setup_args)
        self._queue: list[tuple[int, Job, Any]] = []

    def __enter__(self) -> InProcess:
        pool.setup_here(self._setup[0], *self._setup[1])
        return self

    def __exit__(self, *exc: Any) -> None:
        self._queue.clear()

    def submit(self, key: int, fn: Job, arg: Any) -> None:
        self._queue.append((key, fn, arg))

    def running(self) -> int:
        return len(self._queue)

    def results(self, timeout: float) -> list[tuple[int, Any]]:
        if not self._queue:
            return []
        key, fn, arg = self._queue.pop(0)
        return [(key, fn(arg))]


class LocalPool:
    """`workers` spawned processes on this machine (`pool.spawn_pool`).

    A worker process that dies (killed, out of memory) takes its job with it, and a Pool
    neither says which job that was nor runs it again: when one of the workers is gone, the
    pool starts afresh and every job in flight runs again (jobs are pure, and the driver
    keeps one result per job), up to `max_retries` times per job; then `results` raises.
    The restart waits for the next `results` call, so a driver that was told to stop
    (SIGTERM to the process group kills the workers too) stops without starting workers."""

    separate_processes = True

    def __init__(
        self,
        workers: int,
        setup: pool.Setup,
        setup_args: tuple[Any, ...],
        max_retries: int = pool.MAX_RETRIES,
    ) -> None:
        self.workers = workers
        self.capacity = 2 * workers
        self._setup = (setup, setup_args)
        self._retries = max_retries
        self._pool: Any = None
        self._pids: set[int] = set()
        self._stack = ExitStack()
        self._running: dict[int, Any] = {}
        self._jobs: dict[int, tuple[Job, Any]] = {}  # the running jobs' (fn, arg)
        self._tries: dict[int, int] = {}  # key -> times its run was lost with a worker
        self._lost = False  # a worker died: restart at the next `results`

    def __enter__(self) -> LocalPool:
        self._start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._running.clear()
        self._jobs.clear()
        self._stack.close()  # stops the workers, running jobs or not, without hanging

    def _start(self) -> None:
        self._pool = self._stack.enter_context(pool.spawn_pool(self.workers, *self._setup))
        self._pids = pool.worker_pids(self._pool)

    def submit(self, key: int, fn: Job, arg: Any) -> None:
        self._jobs[key] = (fn, arg)
        self._running[key] = self._pool.apply_async(fn, (arg,))

    def running(self) -> int:
        return len(self._running)

    def results(self, timeout: float) -> list[tuple[int, Any]]:
        if not self._running:
            return []
        if self._lost:
            self._restart()
        ready = [k for k, r in self._running.items() if r.ready()]
        if not ready:
            next(iter(self._running.values())).wait(timeout)
            ready = [k for k, r in self._running.items() if r.ready()]
        out = []
        for key in ready:
            del self._jobs[key]
            out.append((key, self._running.pop(key).get()))
        pids = pool.worker_pids(self._pool)
        if pids != self._pids:  # a worker died (the Pool started another)
            self._lost = bool(self._running)
            if not self._running:  # no job was lost with it
                self._pids = pids
        return out

    def _restart(self) -> None:
        """A worker died: a fresh pool runs every job in flight again (or NgpmError when a
        job's runs were lost more than `max_retries` times)."""
        jobs = list(self._jobs.items())
        for key, _ in jobs:
            self._tries[key] = self._tries.get(key, 0) + 1
        lost = [k for k, _ in jobs if self._tries[k] > self._retries]
        if lost:
            jobs_text = f"job{'s' if len(lost) > 1 else ''} {', '.join(map(str, lost))}"
            raise NgpmError(
                f"worker processes died {self._tries[lost[0]]} times while "
                f"{jobs_text} ran (killed, or out of memory?)"
            )
        self._stack.close()
        self._running.clear()
        self._lost = False
        self._start()
        for key, (fn, arg) in jobs:
            self.submit(key, fn, arg)


def make_backend(
    kind: str,
    workers: int,
    setup: pool.Setup,
    setup_args: tuple[Any, ...],
    address: str | None = None,
) -> Backend:
    """The backend named `kind` ("local" or "ray"); `address` is a Ray cluster's (None: a
    local Ray instance with `workers` CPUs, or the cluster named by $RAY_ADDRESS)."""
    if kind == "local":
        if address:
            raise NgpmError("--ray-address needs --backend ray")
        if workers <= 1:
            return InProcess(setup, setup_args)
        return LocalPool(workers, setup, setup_args)
    if kind == "ray":
        from ngpm_compiler.jobs.ray_backend import RayBackend

        return RayBackend(workers, setup, setup_args, address=address)
    raise NgpmError(f"unknown backend {kind!r}; choose from {', '.join(BACKENDS)}")


def ship_file(path: str | None, kind: str) -> str | bytes | None:
    """What workers get for a file the driver names: its path for the local backend, its
    bytes for Ray (workers on other machines have no such path); None stays None."""
    if path is None or kind == "local":
        return path
    return Path(path).read_bytes()


def load_guide(guide: str | bytes, program: Program) -> Guide:
    """A worker's Guide from a path or from a guide file's bytes (`ship_file`)."""
    from ngpm_runtime.inference.guide import Guide

    if isinstance(guide, str):
        return Guide.load(guide, program)
    with tempfile.TemporaryDirectory(prefix="ngpm_guide_") as tmp:  # read whole by load
        path = Path(tmp) / "guide.onnx"
        path.write_bytes(guide)
        return Guide.load(path, program)
