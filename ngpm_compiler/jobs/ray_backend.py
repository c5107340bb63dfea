"""`RayBackend`: jobs as Ray tasks, on a local Ray instance or on a cluster (`cluster` extra).

The setup's arguments go to the object store once (`ray.put`); each worker process runs the
setup the first time it gets a task of this run and keeps what it built (`pool.state()`), as
a `LocalPool` worker does. A task whose worker dies (killed, out of memory, node lost) is
run again by Ray, up to `pool.MAX_RETRIES` times; its result still reaches the driver once, and
the driver alone writes results, so a retried job is never recorded twice.

Without an address (and without $RAY_ADDRESS) a local Ray instance with `workers` CPUs starts
and is shut down on exit, also when the driver is killed (`ray_reaper.py`); with one, the
driver connects to that cluster and leaves it running.
Every node needs the same Python environment (ngpm installed, same versions) as the driver;
nothing else is read there: no grammar file, no target folder.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import uuid
from typing import Any

from ngpm_runtime.errors import NgpmError

from ngpm_compiler.jobs import pool, ray_reaper

_RUN: list[str] = [""]  # the run whose setup this worker process holds


def _task(run: str, box: list[Any], fn: Any, arg: Any) -> Any:
    """One job in a Ray worker; runs the setup first when this worker has not yet for `run`.

    `box` holds the setup's ObjectRef inside a list, so Ray does not fetch it per task."""
    if _RUN[0] != run:
        import ray

        setup, setup_args = ray.get(box[0])
        pool.setup_here(setup, *setup_args)
        _RUN[0] = run
    return fn(arg)


def import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise NgpmError(
            "--backend ray needs Ray: pip install 'ray>=2.9' (or the cluster "
            "extra: pip install -e '.[cluster]')"
        ) from None
    return ray


def check_reachable(address: str, timeout: float = 10.0) -> None:
    """NgpmError unless something listens at a `host:port` (or `ray://host:port`) address,
    rather than Ray's minutes of retries; 'auto' and other forms are left to Ray."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit() or not host:
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as err:
        raise NgpmError(
            f"cannot reach the Ray cluster at {address} ({err.strerror or err}); "
            "is `ray start --head` running there?"
        ) from None


def start_reaper(pids: set[int]) -> subprocess.Popen[bytes] | None:
    """A `ray_reaper` process for the local instance's processes `pids`: it stops what they
    leave behind once this process has exited, however it ended (None off Linux)."""
    if not sys.platform.startswith("linux") or not pids:
        return None
    return subprocess.Popen(
        [sys.executable, ray_reaper.__file__, *map(str, sorted(pids))],
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def stop_reaper(reaper: subprocess.Popen[bytes] | None) -> None:
    """Close the reaper's pipe (so it kills what the shut-down instance left, then exits)."""
    if reaper is None:
        return
    if reaper.stdin is not None:
        reaper.stdin.close()
    try:
        reaper.wait(timeout=5)
    except subprocess.TimeoutExpired:
        pass


def connect(ray: Any, address: str) -> None:
    """ray.init on a running cluster, with errors that say what to check."""
    check_reachable(address)
    try:
        ray.init(address=address, logging_level="ERROR")
    except ConnectionError as err:
        raise NgpmError(
            f"cannot connect to the Ray cluster at {address} ({err}); a cluster "
            "with token authentication (recent Ray turns it on for `ray start`) "
            "needs RAY_AUTH_MODE=token here, and its token in RAY_AUTH_TOKEN or "
            "~/.ray/auth_token (docs/cluster.md)"
        ) from None


class RayBackend:
    """Jobs as Ray tasks (see the module's docstring)."""

    separate_processes = True

    def __init__(
        self,
        workers: int,
        setup: pool.Setup,
        setup_args: tuple[Any, ...],
        address: str | None = None,
        max_retries: int = pool.MAX_RETRIES,
    ) -> None:
        self.ray = import_ray()
        self.workers = max(1, workers)
        self.address = address
        self.capacity = 2 * self.workers
        self._setup = (setup, setup_args)
        self._retries = max_retries
        self._started = False  # a local instance we started (and shut down on exit)
        self._reaper: subprocess.Popen[bytes] | None = None
        self._running: dict[Any, int] = {}  # ObjectRef -> key
        self._box: list[Any] = []
        self._remote: Any = None
        self._run = uuid.uuid4().hex

    def __enter__(self) -> RayBackend:
        ray = self.ray
        if not ray.is_initialized():
            if self.address or os.environ.get("RAY_ADDRESS"):
                connect(ray, self.address or os.environ["RAY_ADDRESS"])
            else:
                os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
                before = ray_reaper.children(os.getpid())
                ray.init(
                    address="local",
                    num_cpus=self.workers,
                    include_dashboard=False,
                    logging_level="ERROR",
                )  # "local": not a `ray start` cluster here
                self._started = True
                self._reaper = start_reaper(ray_reaper.children(os.getpid()) - before)
        try:
            cpus = int(ray.cluster_resources().get("CPU", self.workers))
            self.capacity = 2 * max(1, cpus)
            self._box = [ray.put(self._setup)]
            self._remote = ray.remote(num_cpus=1, max_retries=self._retries)(_task)
        except BaseException:
            self._shutdown()
            raise
        return self

    def __exit__(self, *exc: Any) -> None:
        try:
            # a local instance we started goes down whole with ray.shutdown(); cancelling
            # its tasks first races the shutdown (Ray's core worker can crash on it)
            for ref in [] if self._started else list(self._running):
                try:
                    self.ray.cancel(ref, force=True)
                except Exception:  # already finished, or the cluster is gone
                    pass
        finally:
            self._running.clear()
            self._box = []
            self._shutdown()

    def _shutdown(self) -> None:
        if self._started:
            self._started = False
            self.ray.shutdown()
            stop_reaper(self._reaper)
            self._reaper = None

    def submit(self, key: int, fn: Any, arg: Any) -> None:
        self._running[self._remote.remote(self._run, self._box, fn, arg)] = key

    def running(self) -> int:
        return len(self._running)

    def results(self, timeout: float) -> list[tuple[int, Any]]:
        if not self._running:
            return []
        refs = list(self._running)
        ready, _ = self.ray.wait(refs, num_returns=1, timeout=timeout)
        if ready:
            ready, _ = self.ray.wait(refs, num_returns=len(refs), timeout=0)
        return [(self._running.pop(ref), self._get(ref)) for ref in ready]

    def _get(self, ref: Any) -> Any:
        """A task's result; a task's own error is raised as itself (Ray's wrapper prints the
        worker's traceback in its message)."""
        try:
            return self.ray.get(ref)
        except self.ray.exceptions.RayTaskError as err:
            if isinstance(err.cause, Exception):
                raise err.cause from None
            raise
