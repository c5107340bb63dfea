"""The one driver loop: it keeps the backend at capacity, stops submitting when there is no
room, hands each key's result back once, and runs `between` after every poll."""

from __future__ import annotations

from typing import Any

from ngpm_compiler.jobs import pool
from ngpm_compiler.jobs.backends import InProcess
from ngpm_compiler.jobs.driver import drive


def _setup() -> dict[str, int]:
    return {}


def _square(x: int) -> int:
    return x * x


class Repeats(InProcess):
    """InProcess, but the first result comes back twice (as from a retried job)."""

    capacity = 3

    def __init__(self) -> None:
        super().__init__(_setup, ())
        self.most_running = 0
        self.repeated = False

    def submit(self, key: int, fn: Any, arg: Any) -> None:
        super().submit(key, fn, arg)
        self.most_running = max(self.most_running, self.running())

    def results(self, timeout: float) -> list[tuple[int, Any]]:
        out = [(k, fn(arg)) for k, fn, arg in self._queue]
        self._queue.clear()
        if out and not self.repeated:
            self.repeated = True
            out.append(out[0])
        return out


def test_every_job_once_at_capacity() -> None:
    got: list[tuple[int, int]] = []
    polls: list[int] = []
    with Repeats() as jobs:
        drive(
            jobs,
            _square,
            iter([(k, k + 1) for k in range(7)]),
            lambda k, r: got.append((k, r)),
            between=lambda: polls.append(1),
        )
    assert got == [(k, (k + 1) ** 2) for k in range(7)]
    assert jobs.most_running == 3 and len(polls) == 3


def test_no_room_stops_an_endless_todo() -> None:
    got: list[int] = []

    def endless() -> Any:
        k = 0
        while True:
            yield k, k
            k += 1

    with InProcess(_setup, ()) as jobs:
        drive(
            jobs,
            _square,
            endless(),
            lambda k, r: got.append(k),
            room=lambda running: len(got) + running < 4,
        )
    assert got == [0, 1, 2, 3]
    assert pool.state() == {}
