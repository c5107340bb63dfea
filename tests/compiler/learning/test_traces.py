"""Trace generation: pure jobs, shards and pending files, kill-and-resume, loading."""

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
from ngpm_runtime.image.targets import save_target
from repo_paths import REPO

from ngpm_compiler.cli.guide import FEATURE_SETS
from ngpm_compiler.learning.nets import FEATURE_SETS as NET_FEATURE_SETS
from ngpm_compiler.learning.shards import TraceError
from ngpm_compiler.learning.trace_data import load_traces
from ngpm_compiler.learning.trace_jobs import MIN_PRIMITIVES, job_arrays, job_spec
from ngpm_compiler.learning.trace_store import TraceStore, save_npz
from ngpm_compiler.learning.traces import TraceConfig, generate_traces


def test_feature_set_names_agree():
    assert FEATURE_SETS == NET_FEATURE_SETS


def test_job_spec_is_pure():
    a = [job_spec(7, i, 5) for i in range(50)]
    assert a == [job_spec(7, i, 5) for i in range(50)]
    assert len({s for _, s in a}) == 50 and {t for t, _ in a} <= set(range(5))
    assert a != [job_spec(8, i, 5) for i in range(50)]


def test_pending_and_shards_deduplicate(tmp_path):
    store = TraceStore(tmp_path)
    f = np.ones((2, 4), np.float32)
    for job in range(4):
        trace = [(0, f[0], 1.0), (1, f[1] * job, 2.0), (0, f[0], 3.0)]
        store.write_pending(job_arrays(job, 0, 100 + job, trace, 12, kept=job != 2))
    store.consolidate()
    assert [p.name for p in store.shard_paths()] == ["shard_00000000.npz"]
    assert store.pending_paths() == []
    # a pending file left behind after its shard was written (killed in between)
    store.write_pending(job_arrays(1, 0, 101, [(0, f[0], 1.0)], 12, kept=True))
    done = store.finished()
    assert sorted(done["jobs"].tolist()) == [0, 1, 2, 3]
    assert done["kept"].tolist() == [True, True, False, True]
    assert done["v_0"].tolist() == [1.0, 3.0, 1.0, 3.0, 1.0, 3.0]
    assert done["j_1"].tolist() == [0, 1, 3]
    store.consolidate()
    assert len(store.shard_paths()) == 1 and store.pending_paths() == []
    (tmp_path / "shard_00000001.npz").write_bytes(b"garbage")
    with pytest.raises(TraceError, match="corrupt"):
        store.finished()


ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "runtime")])}


def run_traces(out: Path, data: Path, n: int, workers: int, **kw) -> subprocess.Popen:
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
        "-o",
        str(out),
        "--workers",
        str(workers),
        "--seed",
        "3",
        "--shard-size",
        "4",
    ]
    return subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV, start_new_session=True, **kw
    )


def test_kill_and_resume(tmp_path):
    data = make_dataset(tmp_path / "data")
    out = tmp_path / "traces"
    # asked for far more jobs than it can finish before the kill (24 could all finish on
    # a fast machine between the check and the kill); jobs are pure and the job count is
    # not part of the configuration, so the rerun asks for fewer
    proc = run_traces(out, data, 2000, workers=2)
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if finished_jobs(out) >= 6 and TraceStore(out).shard_paths():
            break
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()[1][-2000:]
    os.killpg(proc.pid, signal.SIGKILL)  # the run and its workers, mid-run
    proc.wait()
    before = finished_jobs(out)
    assert 6 <= before < 2000 and TraceStore(out).shard_paths()  # killed after some shards
    n = int(TraceStore(out).finished()["jobs"].max()) + 1 + 12  # every finished job, and more
    proc = run_traces(out, data, n, workers=2)
    _, err = proc.communicate(timeout=180)
    assert proc.returncode == 0, err[-2000:]
    ts = load_traces(out)
    assert len(ts.kept_jobs) == n and len(np.unique(ts.kept_jobs)) == n
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["kept"] == n and manifest["dropped"] == 0  # chain: always 12 segments
    assert sorted(ts.kept_jobs.tolist()) == list(range(n))
    # the same traces as one uninterrupted single-process run (jobs are pure)
    ref_out = tmp_path / "ref"
    generate_traces(
        TraceConfig(
            grammar=CHAIN, targets=str(data), n=n, particles=8, seed=3, workers=1, shard_size=4
        ),
        ref_out,
        progress=False,
    )
    ref = load_traces(ref_out)
    assert sorted(ref.data) == sorted(ts.data) == [0]
    a, b = ref.data[0], ts.data[0]
    oa, ob = np.argsort(a.jobs, kind="stable"), np.argsort(b.jobs, kind="stable")
    assert np.array_equal(a.jobs[oa], b.jobs[ob])
    assert np.array_equal(a.values[oa], b.values[ob])
    assert np.array_equal(a.features[oa], b.features[ob])
    assert np.array_equal(a.prior_args[:, 1], np.full(len(a.values), 25.0))  # gauss(0, TURN)


def test_resume_refuses_other_configuration(tmp_path):
    data = make_dataset(tmp_path / "data", 2)
    cfg = TraceConfig(grammar=CHAIN, targets=str(data), n=2, particles=4, workers=1)
    generate_traces(cfg, tmp_path / "t", progress=False)
    cfg.particles = 5
    with pytest.raises(TraceError, match="particles"):
        generate_traces(cfg, tmp_path / "t", progress=False)
    # a key without the fields it always has now (max_modules, guide: None when unset)
    cfg.particles = 4
    manifest = tmp_path / "t" / "manifest.json"
    m = json.loads(manifest.read_text())
    m["key"] = {k: v for k, v in m["key"].items() if k not in ("max_modules", "guide")}
    manifest.write_text(json.dumps(m))
    with pytest.raises(
        TraceError,
        match=r"another configuration \(differs in guide, "
        r"max_modules\); use a new directory",
    ):
        generate_traces(cfg, tmp_path / "t", progress=False)
    with pytest.raises(TraceError, match="not a traces directory"):
        load_traces(tmp_path / "data")


def test_traces_of_an_older_layout_are_not_resumed_nor_trained_on_by_new_groups(tmp_path):
    """A traces directory recorded before the far group (rows end at the context group)
    is not resumed with wider rows, and a feature set reading far refuses it in one line;
    the sets it has train as before."""
    from ngpm_runtime.errors import NgpmError

    from ngpm_compiler.learning.train import TrainConfig, train_guide

    data = make_dataset(tmp_path / "data", 2)
    cfg = TraceConfig(grammar=CHAIN, targets=str(data), n=2, particles=4, workers=1)
    generate_traces(cfg, tmp_path / "t", progress=False)
    manifest = tmp_path / "t" / "manifest.json"
    m = json.loads(manifest.read_text())
    for lay in m["layouts"].values():
        del lay["far"]
    manifest.write_text(json.dumps(m))
    for shard in (tmp_path / "t").glob("shard_*.npz"):  # rows as they were recorded then
        z = dict(np.load(shard))
        for k in [k for k in z if k.startswith("f_")]:
            z[k] = z[k][:, : m["layouts"][k[2:]]["context"][1]]
        save_npz(shard, z)
    cfg.n = 3
    with pytest.raises(TraceError, match="another layout .*use a new directory"):
        generate_traces(cfg, tmp_path / "t", progress=False)
    ts = load_traces(tmp_path / "t")
    with pytest.raises(NgpmError, match="reads the 'far' group, which these traces do not"):
        train_guide(ts.sites, ts.layouts, ts.data, TrainConfig("all+context+far", epochs=1))
    model = train_guide(ts.sites, ts.layouts, ts.data, TrainConfig("all+context", epochs=1))
    assert model.nets


def test_mirror_adds_missing_copies(tmp_path):
    from ngpm_compiler.learning.trace_jobs import load_targets

    data = make_dataset(tmp_path / "data", 2)
    names = [t.name for t in load_targets(data, 50, mirror=True)]
    assert names == ["bar0", "bar1", "bar0_m", "bar1_m"]
    t = load_targets(data, 50, mirror=True)[0].mirrored()
    save_target(t, data / "bar0_m.png")
    assert sorted(t.name for t in load_targets(data, 50, mirror=True)) == [
        "bar0",
        "bar0_m",
        "bar1",
        "bar1_m",
    ]


def test_failed_smc_jobs_are_dropped_and_counted(tmp_path, monkeypatch):
    from ngpm_runtime.errors import SMCFailed

    import ngpm_compiler.learning.trace_workers as workers_mod

    real = workers_mod.run_job

    def flaky(program, target, seed, particles, **kw):
        if seed % 3 == 0:
            raise SMCFailed("every particle's weight is zero")
        return real(program, target, seed, particles, **kw)

    monkeypatch.setattr(workers_mod, "run_job", flaky)
    data = make_dataset(tmp_path / "data", 2)
    m = generate_traces(
        TraceConfig(grammar=CHAIN, targets=str(data), n=6, particles=4, workers=1),
        tmp_path / "t",
        progress=False,
    )
    failing = sum(job_spec(0, j, 2)[1] % 3 == 0 for j in range(m["jobs_done"]))
    assert failing >= 1 and m["kept"] == 6 and m["failed"] == m["dropped"] == failing
    assert len(load_traces(tmp_path / "t").kept_jobs) == 6


def cli(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    """ngpmc in a subprocess; the test fails (TimeoutExpired) if it hangs."""
    return subprocess.run(
        [sys.executable, "-m", "ngpm_compiler.cli", *args],
        env=ENV,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_traces_refuses_a_guide_that_does_not_fit_before_starting_workers(tmp_path):
    """A guide of another grammar, or a corrupt one, used to make every worker fail its
    setup, and the pool start a new one each time, forever."""
    from ngpm_runtime import bundled

    data = make_dataset(tmp_path / "data", 2)
    corrupt = tmp_path / "corrupt.onnx"
    corrupt.write_bytes(bundled.guide_path().read_bytes()[:1000])
    for guide, words in (
        (bundled.guide_path(), "guide was trained for grammar 'vines'"),
        (corrupt, "not a readable ONNX guide (corrupt or truncated file)"),
    ):
        out = tmp_path / "tr"
        proc = cli(
            "traces",
            CHAIN,
            "--targets",
            str(data),
            "-n",
            "2",
            "--particles",
            "4",
            "--workers",
            "2",
            "-o",
            str(out),
            "--guide",
            str(guide),
        )
        assert proc.returncode == 1 and proc.stderr.startswith(f"ngpmc: error: {guide}: ")
        assert words in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
        assert not out.exists()


class Hung(Exception):
    pass


def _hung(signum, frame):
    raise Hung("still running after the test's deadline")


def within(seconds: float, fn, *args, **kw):
    """fn(*args, **kw), interrupted by Hung (the test fails) after `seconds`."""
    old = signal.signal(signal.SIGALRM, _hung)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        return fn(*args, **kw)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def test_a_killed_pool_worker_costs_only_a_rerun(tmp_path):
    """SIGKILL of a local-pool worker mid-run used to stall `traces` forever (its job never
    came back); now its jobs run again, and the shards are the same bytes."""
    import multiprocessing as mp

    data = make_dataset(tmp_path / "data", 2)
    cfg = TraceConfig(
        grammar=CHAIN, targets=str(data), n=12, particles=30, seed=3, workers=2, shard_size=4
    )
    killed: list[int] = []

    def kill_one(job: int) -> None:
        workers = [p for p in mp.active_children() if p.name.startswith("SpawnPoolWorker")]
        if not killed and job >= 2 and workers:
            os.kill(workers[0].pid, signal.SIGKILL)
            killed.append(workers[0].pid)

    m = within(90, generate_traces, cfg, tmp_path / "killed", progress=False, on_job=kill_one)
    assert killed and m["kept"] == m["jobs_done"] == 12
    cfg.workers = 1
    generate_traces(cfg, tmp_path / "ref", progress=False)
    shards = sorted(p.name for p in (tmp_path / "ref").glob("shard_*.npz"))
    assert shards == sorted(p.name for p in (tmp_path / "killed").glob("shard_*.npz"))
    for name in shards:
        assert (tmp_path / "killed" / name).read_bytes() == (tmp_path / "ref" / name).read_bytes()


def test_disk_full_at_the_last_shard_keeps_the_finished_traces(tmp_path, monkeypatch):
    """ENOSPC from the last shard's write on (the manifest's too) used to leave no
    manifest.json, and `train` refused the folder; now the manifest of the shards written is
    there, the other jobs stay pending, and a rerun writes the same last shard."""
    import errno

    import ngpm_compiler.learning.trace_store as store_mod

    data = make_dataset(tmp_path / "data", 2)
    cfg = TraceConfig(grammar=CHAIN, targets=str(data), n=6, particles=4, workers=1, shard_size=4)
    real, full = store_mod.atomic_write, []

    def write(path, data):
        if full or Path(path).name == "shard_00000004.npz":
            full.append(Path(path).name)
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, data)

    monkeypatch.setattr(store_mod, "atomic_write", write)
    out = tmp_path / "full"
    with pytest.raises(OSError, match="No space left on device"):
        generate_traces(cfg, out, progress=False)
    monkeypatch.undo()
    assert full == ["shard_00000004.npz", "manifest.json"]
    assert [p.name for p in TraceStore(out).shard_paths()] == ["shard_00000000.npz"]
    assert json.loads((out / "manifest.json").read_text())["shards"] == ["shard_00000000.npz"]
    assert sorted(load_traces(out).kept_jobs.tolist()) == list(range(6))  # 4, 5 pending
    m = generate_traces(cfg, out, progress=False)
    assert m["kept"] == 6 and m["shards"] == ["shard_00000000.npz", "shard_00000004.npz"]
    generate_traces(cfg, tmp_path / "ref", progress=False)
    for name in m["shards"]:
        assert (out / name).read_bytes() == (tmp_path / "ref" / name).read_bytes()


F3 = "viewport: -10 10 -10 10\nAxiom: F F F\nendlsystem\n"  # always 3 primitives


def test_short_traces_are_kept_unless_asked_to_drop(tmp_path):
    """By default a job whose best particle drew few primitives is kept as data (as `ngpmc
    learn` keeps it); --min-primitives drops it; a directory recorded under another
    threshold says which to pass to resume it."""
    grammar = tmp_path / "f3.lsys"
    grammar.write_text(F3)
    data = make_dataset(tmp_path / "data", 2)
    cfg = TraceConfig(grammar=str(grammar), targets=str(data), n=2, particles=4, workers=1)
    assert cfg.min_primitives == MIN_PRIMITIVES == 1
    m = generate_traces(cfg, tmp_path / "kept", progress=False)
    assert (m["kept"], m["dropped"]) == (2, 0)
    assert len(load_traces(tmp_path / "kept").kept_jobs) == 2
    cfg.min_primitives = 4
    with pytest.raises(
        TraceError,
        match=r"differs in min_primitives\); use a new directory or "
        r"--min-primitives 1 to resume it",
    ):
        generate_traces(cfg, tmp_path / "kept", progress=False)
    cfg.n = 1
    with pytest.raises(TraceError, match="fewer than 4 primitives"):
        generate_traces(cfg, tmp_path / "dropped", progress=False)
    m = json.loads((tmp_path / "dropped" / "manifest.json").read_text())
    assert m["kept"] == 0 and m["dropped"] >= 50


def test_circuit_traces_grow_into_a_blank_canvas_from_the_bottom_middle(
    tmp_path, capsys, monkeypatch
):
    """--likelihood circuit: no targets; every job grows under equation 2 from the start of
    grow.circuit_target, and the recorded rows are what circuit SMC with a guide sees (as
    `grow` runs it: no target features)."""
    from ngpm_runtime import warmup
    from ngpm_runtime.grow import grow
    from ngpm_runtime.inference.smc import TraceRecording

    from ngpm_compiler.cli import main
    from ngpm_compiler.language.compile import load_grammar

    monkeypatch.setattr(warmup, "cache_is_cold", lambda: False)  # no note on stderr
    out = tmp_path / "t"
    argv = ["traces", CHAIN, "--likelihood", "circuit", "-n", "2", "--particles", "6"]
    assert main([*argv, "-o", str(out), "--workers", "1"]) == 0
    capsys.readouterr()
    m = json.loads((out / "manifest.json").read_text())
    assert m["key"]["likelihood"] == "circuit" and m["key"]["targets"] == ["circuit"]
    ts = load_traces(out)
    assert len(ts.kept_jobs) == 2
    # job 0 again, in this process: the rows of its best particle under the circuit likelihood
    program = load_grammar(CHAIN)
    _, seed = job_spec(0, 0, 1)
    best = grow(program, None, None, 6, seed, "circuit", trace=TraceRecording.FULL).smc.best
    site, feats, _ = best.trace[0]
    rows = ts.data[site].features[ts.data[site].jobs == 0]
    assert np.array_equal(rows[0], feats)
    assert feats[0] == 0.0 and feats[1] == pytest.approx(-0.9)  # bottom middle: x, y in [-1, 1]
    # the shape likelihood needs targets, the circuit likelihood takes none: one line each
    for extra, want in (
        (["--targets", str(tmp_path)], "the circuit likelihood has no targets: drop --targets"),
        (["--mirror"], "--mirror mirrors targets: the circuit likelihood has none"),
    ):
        assert main([*argv, "-o", str(tmp_path / "x"), *extra]) == 1
        err = capsys.readouterr().err
        assert want in err and len(err.strip().splitlines()) == 1, err
    assert main(["traces", CHAIN, "-n", "2", "-o", str(tmp_path / "x")]) == 1
    err = capsys.readouterr().err
    assert "the shape likelihood needs --targets" in err and len(err.strip().splitlines()) == 1
    # a shape run on the circuit traces' directory is another configuration
    data = make_dataset(tmp_path / "data", 2)
    shape = TraceConfig(grammar=CHAIN, targets=str(data), n=2, particles=6, workers=1)
    with pytest.raises(TraceError, match="differs in .*likelihood"):
        generate_traces(shape, out, progress=False)


def test_own_samples_record_each_forward_sample_into_its_own_envelope(tmp_path, capsys):
    """--own-samples: no SMC and no targets; job i draws a forward sample, and its rows are
    the features that sample's own values get in the envelope of what they draw (replayed
    here: the values draw it again, and its envelope is the target the rows saw). A rerun
    with a larger -n resumes; targets, a guide or mirroring are refused in one line."""
    from ngpm_runtime.image.targets import Target
    from ngpm_runtime.inference.smc import replay

    from ngpm_compiler.cli import main
    from ngpm_compiler.datasets.envelopes import MIN_INK, envelope, start_of
    from ngpm_compiler.language.compile import load_grammar

    plant = str(REPO / "grammars" / "stochastic_plant.lsys")
    cfg = TraceConfig(grammar=plant, targets="", n=3, particles=1, workers=1, own_samples=True)
    m = generate_traces(cfg, tmp_path / "own", progress=False)
    assert m["kept"] == 3 and m["key"]["own_samples"] and m["key"]["targets"] == []
    program = load_grammar(plant)
    ts = load_traces(tmp_path / "own")
    (site,) = ts.data  # the plant's one site: its rows in visit order
    data = ts.data[site]
    masks = []
    for job in range(3):
        rows, values = data.features[data.jobs == job], data.values[data.jobs == job]
        drawn = replay(program, [(site, v) for v in values])
        mask = envelope(list(drawn.primitives), program, 50)
        assert mask.mean() >= MIN_INK
        target = Target(mask, start_of(program), "own")
        again = replay(
            program,
            [(site, v) for v in values],
            start=target.start_pose(program.viewport),
            canvas_size=target.size,
            target_mask=mask,
        )
        assert np.array_equal(np.stack([f for _, f, _ in again.trace]), rows)
        masks.append(mask)
    assert not np.array_equal(masks[0], masks[1])  # each job its own sample
    cfg.n = 5
    assert generate_traces(cfg, tmp_path / "own", progress=False)["kept"] == 5
    again_ts = load_traces(tmp_path / "own")
    first = again_ts.data[site].jobs < 3
    assert np.array_equal(again_ts.data[site].features[first], data.features)
    # the command line: the flag, and one-line refusals
    argv = ["traces", plant, "--own-samples", "-n", "2", "--workers", "1"]
    assert main([*argv, "-o", str(tmp_path / "cli")]) == 0
    assert "2 traces kept" in capsys.readouterr().out
    for extra in (["--targets", str(tmp_path)], ["--mirror"]):
        assert main([*argv, "-o", str(tmp_path / "x"), *extra]) == 1
        err = capsys.readouterr().err
        assert "ground-truth traces make their own targets" in err, err
        assert len(err.strip().splitlines()) == 1


def test_own_samples_of_a_grammar_that_draws_too_little_stop_with_the_cause(tmp_path):
    """Three unit strokes in a 200-unit viewport never cover 3% of the canvas: after 50
    jobs in a row found no such sample, one error says what to change."""
    grammar = tmp_path / "tiny.lsys"
    grammar.write_text(F3.replace("-10 10 -10 10", "-100 100 -100 100"))
    cfg = TraceConfig(grammar=str(grammar), targets="", n=1, workers=1, own_samples=True)
    with pytest.raises(TraceError, match="covers 3% of the canvas; fit the viewport"):
        generate_traces(cfg, tmp_path / "own", progress=False)
