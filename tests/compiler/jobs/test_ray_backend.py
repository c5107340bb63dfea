"""`--backend ray` on a local Ray instance (one per module: Ray takes seconds to start): the
same shard bytes as the local backend, a killed worker's job retried and recorded once, a
SIGTERM that cancels the run, writes the manifest and leaves no Ray process behind."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from fixtures.datasets import CHAIN, make_dataset
from fixtures.trace_dirs import finished_jobs
from repo_paths import REPO

ray = pytest.importorskip("ray", reason="ray is not installed (pip install -e '.[cluster]')")

from ngpm_compiler.cli import main  # noqa: E402
from ngpm_compiler.learning.trace_data import load_traces  # noqa: E402
from ngpm_compiler.learning.trace_store import TraceStore  # noqa: E402
from ngpm_compiler.learning.traces import TraceConfig, generate_traces  # noqa: E402

N, PARTICLES, SEED, SHARD = 24, 30, 3, 4


@pytest.fixture(scope="module")
def local_ray():
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="ERROR")
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> tuple[Path, dict[str, bytes]]:
    """The dataset and the shards of the local backend (2 worker processes)."""
    root = tmp_path_factory.mktemp("ray_ref")
    data = make_dataset(root / "data")
    generate_traces(config(data, backend="local"), root / "local", progress=False)
    return data, shard_bytes(root / "local")


def config(data: Path, **kw) -> TraceConfig:
    return TraceConfig(
        grammar=CHAIN,
        targets=str(data),
        n=N,
        particles=PARTICLES,
        seed=SEED,
        workers=2,
        shard_size=SHARD,
        **kw,
    )


def shard_bytes(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in TraceStore(out).shard_paths()}


def test_ray_shards_equal_the_local_backends(local_ray, reference, tmp_path):
    data, want = reference
    assert sorted(want) == [f"shard_{i:08d}.npz" for i in range(0, N, SHARD)]
    out = tmp_path / "ray"
    assert (
        main(
            [
                "traces",
                CHAIN,
                "--targets",
                str(data),
                "-n",
                str(N),
                "--particles",
                str(PARTICLES),
                "--seed",
                str(SEED),
                "--shard-size",
                str(SHARD),
                "-o",
                str(out),
                "--backend",
                "ray",
            ]
        )
        == 0
    )
    assert shard_bytes(out) == want
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["kept"] == N and manifest["config"]["backend"] == "ray"
    assert ray.is_initialized()  # a Ray instance it did not start is left running


def test_eval_runs_on_ray_equal_local_runs(local_ray):
    """`ngpmc eval --backend ray`'s run matrix: the grammar's text and the guide's bytes are
    sent; every run's result equals the in-process run's."""
    from ngpm_runtime import bundled

    from ngpm_compiler.evaluation.runs import UNGUIDED, run_tasks, shape_tasks

    targets = {"demo": bundled.demo_targets()[:2]}
    guides = {"all": str(bundled.guide_path())}
    tasks = shape_tasks([UNGUIDED, "all"], {"demo": 2}, [2], 2)
    vines = str(REPO / "grammars" / "vines.lsys")
    local = run_tasks(vines, targets, guides, tasks, workers=1)
    remote = run_tasks(vines, targets, guides, tasks, workers=2, backend="ray")
    assert [r.task for r in remote] == tasks
    assert [(r.similarity, r.primitives) for r in remote] == [
        (r.similarity, r.primitives) for r in local
    ]


def running_task_workers() -> list[int]:
    """Our Ray workers (children of the raylet this process started) running a task."""
    me, out = os.getpid(), []
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            title = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0]
            parent = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
            grand = int(Path(f"/proc/{parent}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        if title.startswith(b"ray::_task") and grand == me:
            out.append(int(pid))
    return out


def test_killed_worker_job_is_retried_once(local_ray, reference, tmp_path):
    data, want = reference
    killed: list[int] = []

    def kill_one(job: int) -> None:
        if len(killed) < 2 and job % 5 == 0:
            pids = running_task_workers()
            if pids:
                os.kill(pids[0], signal.SIGKILL)
                killed.append(pids[0])

    out = tmp_path / "ray"
    m = generate_traces(config(data, backend="ray"), out, progress=False, on_job=kill_one)
    assert killed, "no Ray worker was found running a task"
    assert m["kept"] == m["jobs_done"] == N
    ts = load_traces(out)
    assert sorted(ts.kept_jobs.tolist()) == list(range(N))
    assert shard_bytes(out) == want


def start_driver(data: Path, out: Path, n: int, jobs: int = 10) -> subprocess.Popen:
    """`ngpmc traces --backend ray` (its own local Ray instance) in a session of its own,
    once it has finished `jobs` jobs."""
    cmd = [
        sys.executable,
        "-m",
        "ngpm_compiler.cli",
        "traces",
        CHAIN,
        "--targets",
        str(data),
        "-n",
        str(n),
        "--particles",
        "8",
        "--seed",
        "1",
        "--shard-size",
        str(SHARD),
        "-o",
        str(out),
        "--backend",
        "ray",
    ]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "runtime")])}
    env.pop("RAY_ADDRESS", None)
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, start_new_session=True
    )
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if finished_jobs(out) >= jobs:
            break
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()[1][-2000:]
    assert session_processes(proc.pid) - {proc.pid}  # Ray's processes, in its session
    return proc


def test_sigterm_cancels_and_resumes(tmp_path):
    """A driver with its own local Ray instance, stopped by SIGTERM mid-run; then resumed."""
    data = make_dataset(tmp_path / "data")
    out, n = tmp_path / "traces", 120
    proc = start_driver(data, out, n)
    store = TraceStore(out)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err[-2000:]
    manifest = json.loads((out / "manifest.json").read_text())
    assert 10 <= manifest["jobs_done"] < n
    assert manifest["jobs_done"] == len(np.unique(store.finished()["jobs"]))
    deadline = time.time() + 20
    while session_processes(proc.pid) and time.time() < deadline:
        time.sleep(0.2)
    assert not session_processes(proc.pid)  # the local Ray instance was shut down
    m = generate_traces(
        TraceConfig(
            grammar=CHAIN, targets=str(data), n=n, particles=8, seed=1, workers=2, shard_size=SHARD
        ),
        out,
        progress=False,
    )
    assert m["kept"] == m["jobs_done"] == n
    assert sorted(load_traces(out).kept_jobs.tolist()) == list(range(n))
    assert [p.name for p in store.shard_paths()] == [
        f"shard_{i:08d}.npz" for i in range(0, n, SHARD)
    ]


def test_sigkill_of_the_driver_leaves_no_ray_process(tmp_path):
    """kill -9 of a driver with its own local Ray instance: Ray's agents used to linger for
    a minute or more; the reaper (ray_reaper.py) stops them."""
    proc = start_driver(make_dataset(tmp_path / "data"), tmp_path / "traces", 5000, jobs=4)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate()
    deadline = time.time() + 15
    while session_processes(proc.pid) and time.time() < deadline:
        time.sleep(0.2)
    assert not session_processes(proc.pid)


def session_processes(sid: int) -> set[int]:
    """Live processes of session `sid` (zombies excluded)."""
    out = set()
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            out.add(int(pid))
    return out


def test_a_task_whose_setup_fails_raises_its_own_one_line_error(local_ray, reference):
    """Ray's RayTaskError carries the worker's traceback in its message; the driver raises
    the task's own error instead (one line from ngpmc)."""
    from ngpm_runtime.errors import GuideError

    from ngpm_compiler.jobs.ray_backend import RayBackend
    from ngpm_compiler.learning.trace_jobs import load_targets
    from ngpm_compiler.learning.trace_workers import do_job, worker_setup

    data, _ = reference
    text = Path(CHAIN).read_text(encoding="utf-8")
    setup_args = (CHAIN, text, load_targets(data, 50, False), b"not an onnx file")
    with pytest.raises(GuideError) as info:
        with RayBackend(2, worker_setup, setup_args) as jobs:
            jobs.submit(0, do_job, (0, SEED, PARTICLES, 10, None))
            while jobs.running():
                jobs.results(0.05)
    assert "not a readable ONNX guide" in str(info.value)
    assert "\n" not in str(info.value) and type(info.value) is GuideError
