"""Backends: the in-process and local-pool backends, backend choice and its errors (the Ray
backend's own tests are in test_ray_backend.py)."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import pytest
from ngpm_runtime.errors import NgpmError

from ngpm_compiler.jobs import pool
from ngpm_compiler.jobs.backends import InProcess, LocalPool, make_backend


def _setup(offset: int) -> dict[str, int]:
    return {"offset": offset}


def _job(x: int) -> tuple[int, int]:
    return x + pool.state()["offset"], x


def _drain(
    backend, keys: list[int], job=_job, arg=lambda k: k * 10, seconds: float = 60
) -> dict[int, object]:
    """Every job's result; fails (rather than hangs) when they have not come back in time."""
    out: dict[int, object] = {}
    deadline = time.monotonic() + seconds
    with backend as b:
        for k in keys:
            b.submit(k, job, arg(k))
        while b.running():
            assert time.monotonic() < deadline, f"only {sorted(out)} came back"
            for k, r in b.results(0.05):
                assert k not in out
                out[k] = r
    return out


def test_local_backends_run_every_job_once():
    keys = list(range(6))
    want = {k: (k * 10 + 7, k * 10) for k in keys}
    assert _drain(make_backend("local", 1, _setup, (7,)), keys) == want
    assert isinstance(make_backend("local", 1, _setup, (7,)), InProcess)
    backend = make_backend("local", 2, _setup, (7,))
    assert isinstance(backend, LocalPool) and backend.capacity == 4
    assert _drain(backend, keys) == want


def test_backend_choice_errors(monkeypatch):
    with pytest.raises(NgpmError, match="unknown backend"):
        make_backend("slurm", 2, _setup, (0,))
    with pytest.raises(NgpmError, match="--ray-address needs --backend ray"):
        make_backend("local", 2, _setup, (0,), address="10.0.0.1:6379")
    monkeypatch.setitem(sys.modules, "ray", None)  # as if ray were not installed
    with pytest.raises(NgpmError, match="pip install"):
        make_backend("ray", 2, _setup, (0,))


def test_grammar_from_text_is_the_same_program(tmp_path):
    from fixtures.datasets import CHAIN

    from ngpm_compiler.language.compile import compile_grammar, load_grammar, write_compiled

    text = open(CHAIN, encoding="utf-8").read()
    a, b = load_grammar(CHAIN), load_grammar(CHAIN, text)
    assert (a.name, a.grammar_hash, a.source) == (b.name, b.grammar_hash, b.source)
    sampler, _ = write_compiled(compile_grammar(CHAIN), tmp_path)
    c = load_grammar(sampler, sampler.read_text(encoding="utf-8"))
    assert (c.name, c.grammar_hash) == (a.name, a.grammar_hash)
    assert [s.to_json() for s in c.sites] == [s.to_json() for s in a.sites]


class _Twice(InProcess):
    """Every result comes back twice (as a job retried after its worker died may)."""

    def results(self, timeout: float) -> list[tuple[int, object]]:
        return [x for x in super().results(timeout) for _ in range(2)]


def test_driver_records_a_job_once_however_often_it_returns(tmp_path, monkeypatch):
    from fixtures.datasets import CHAIN, make_dataset

    from ngpm_compiler.jobs import backends
    from ngpm_compiler.learning.trace_data import load_traces
    from ngpm_compiler.learning.traces import TraceConfig, generate_traces

    data = make_dataset(tmp_path / "data", 2)
    cfg = TraceConfig(grammar=CHAIN, targets=str(data), n=6, particles=4, workers=1, shard_size=4)
    monkeypatch.setattr(
        backends,
        "make_backend",
        lambda kind, workers, setup, args, address=None: _Twice(setup, args),
    )
    m = generate_traces(cfg, tmp_path / "twice", progress=False)
    assert m["kept"] == m["jobs_done"] == 6 and len(m["job_seconds"]) == 6
    assert sorted(load_traces(tmp_path / "twice").kept_jobs.tolist()) == list(range(6))
    assert m["shards"] == ["shard_00000000.npz", "shard_00000004.npz"]


def test_unreachable_ray_address_fails_at_once():
    from ngpm_compiler.jobs.ray_backend import check_reachable

    with pytest.raises(NgpmError, match="cannot reach the Ray cluster at 127.0.0.1:1"):
        check_reachable("127.0.0.1:1", timeout=2)
    check_reachable("auto")  # left to Ray


def _failing_setup(kind: str) -> dict[str, int]:
    if kind == "ngpm":
        raise NgpmError("guide.onnx: guide was trained for grammar 'vines', not 'chain'")
    raise ValueError("no such thing")


@pytest.mark.parametrize(
    "kind, words",
    [
        ("ngpm", "guide.onnx: guide was trained for grammar 'vines', not 'chain'"),
        ("other", "a worker process could not start: ValueError: no such thing"),
    ],
)
def test_a_worker_whose_setup_fails_fails_the_first_job(kind: str, words: str) -> None:
    """It used to exit, and the Pool started another in its place, forever."""
    t0 = time.monotonic()
    with pytest.raises(NgpmError) as info:
        _drain(LocalPool(2, _failing_setup, (kind,)), [0, 1, 2], seconds=30)
    assert str(info.value) == words and time.monotonic() - t0 < 30


def _dies_once(arg: tuple[int, str, int]) -> int:
    """Job `key`: SIGKILLs its own worker process the first `times` times it runs."""
    key, folder, times = arg
    runs = sorted(Path(folder).glob(f"{key}_*"))
    if len(runs) < times:
        Path(folder, f"{key}_{len(runs)}").touch()
        os.kill(os.getpid(), signal.SIGKILL)
    time.sleep(0.2)
    return key


def test_local_pool_runs_the_job_of_a_killed_worker_again(tmp_path: Path) -> None:
    """A worker killed mid-job used to leave its job unfinished forever."""
    got = _drain(
        LocalPool(2, _setup, (0,)),
        list(range(5)),
        _dies_once,
        lambda k: (k, str(tmp_path), int(k == 2)),
    )
    assert got == {k: k for k in range(5)} and len(list(tmp_path.glob("2_*"))) == 1
    (tmp_path / "always").mkdir()
    with pytest.raises(
        NgpmError,
        match=r"worker processes died 2 times while job 1 ran "
        r"\(killed, or out of memory\?\)",
    ):
        _drain(
            LocalPool(1, _setup, (0,), max_retries=1),
            [1],
            _dies_once,
            lambda k: (k, str(tmp_path / "always"), 99),
        )
