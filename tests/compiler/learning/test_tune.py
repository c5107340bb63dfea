"""`ngpmc tune`: the settings grid, settings in the guide's metadata (read by Guide.load and
grow), the validation run (cached, resumable) and the CLI's errors."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import onnx
import pytest
from fixtures.guides import perturbed_guide
from fixtures.interrupt import interrupt_after
from ngpm_runtime import bundled
from ngpm_runtime.errors import GuideError
from ngpm_runtime.grow import grow
from ngpm_runtime.image.targets import Target, save_target
from ngpm_runtime.inference.guide import PROPOSAL_KEY, Guide, ProposalSettings
from repo_paths import REPO

from ngpm_compiler.cli import main
from ngpm_compiler.evaluation import heldout
from ngpm_compiler.evaluation.heldout import HELDOUT_FIELDS
from ngpm_compiler.evaluation.runcache import read_runs
from ngpm_compiler.learning.tune import grid, name, tune, tune_table, with_settings

VINES = str(REPO / "grammars" / "vines.lsys")


def bars(directory: Path, n: int = 2) -> Path:
    directory.mkdir(parents=True)
    for i in range(n):
        mask = np.zeros((50, 50), bool)
        mask[8:44, 18 + 4 * i : 26 + 4 * i] = True
        mask[8:16, 10:40] = True
        save_target(Target(mask, (0.45, 0.9, 0.0, -1.0), f"t{i}"), directory / f"t{i}.png")
    return directory


def test_grid_puts_the_untouched_networks_first_and_names_settings() -> None:
    got = grid((1.0,), (0.5, 1.0), (0.5, None))
    assert [name(s) for s in got] == [
        "T1_Tc0.5_ess0.5",
        "T1_Tc0.5_essnone",
        "T1_Tc1_ess0.5",
        "T1_Tc1_essnone",
    ]
    assert len(grid((1.0, 1.0), (0.3,), (None,))) == 1
    with pytest.raises(GuideError, match="choice_temperature"):
        grid((1.0,), (0.0,), (None,))
    with pytest.raises(GuideError, match="ess_threshold"):
        ProposalSettings(ess_threshold=1.5)


def test_settings_travel_in_the_guide_file(tmp_path: Path) -> None:
    program = bundled.bundled_program()
    src = with_settings(bundled.guide_path(), tmp_path / "plain.onnx", ProposalSettings())
    assert Guide.load(src, program).settings == ProposalSettings()
    st = ProposalSettings(temperature=1.3, choice_temperature=0.3, ess_threshold=0.5)
    out = with_settings(src, tmp_path / "tuned.onnx", st)
    onnx.checker.check_model(onnx.load(str(out)), full_check=True)
    g = Guide.load(out, program)
    assert g.settings == st
    assert "proposes with T=1.3,Tc=0.3,ess=0.5 (ngpmc tune)" in bundled.guide_summary(g)
    assert "proposes" not in bundled.guide_summary(Guide.load(src, program))
    # the same networks: only the proposal they describe is sharper
    plain = Guide.load(src, program)
    f = np.zeros((3, plain.nets[2]["n_f"]), np.float32)
    f[:, 0] = [0.0, 0.5, 1.0]
    p, q = plain.params(2, f), g.params(2, f)  # site 2: the choice of L
    np.testing.assert_allclose(
        q, p ** (1 / 0.3) / (p ** (1 / 0.3)).sum(1, keepdims=True), rtol=1e-6
    )
    assert Guide.load(out, program, settings=ProposalSettings()).settings == ProposalSettings()
    # grow resamples by the guide's ESS threshold: fewer resamples than steps
    target = Target(np.pad(np.ones((30, 12), bool), ((10, 10), (19, 19))), (0.5, 0.8, 0, -1))
    tuned = grow(program, target, g, 10, seed=1).smc
    every = grow(program, target, plain, 10, seed=1).smc
    # every step but the last resamples without a threshold; with it, some steps do not
    assert every.info["resamples"] >= every.steps - 1
    assert tuned.info["resamples"] < tuned.steps - 2


def test_corrupt_settings_are_a_one_line_error(tmp_path: Path) -> None:
    proto = onnx.load(str(bundled.guide_path()))
    onnx.helper.set_model_props(
        proto,
        {**{p.key: p.value for p in proto.metadata_props}, PROPOSAL_KEY: '{"temperature": -1}'},
    )
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(proto.SerializeToString())
    with pytest.raises(GuideError, match="bad.onnx: guide proposal settings are corrupt"):
        Guide.load(bad, bundled.bundled_program())


def test_tune_picks_the_best_setting_and_resumes(tmp_path: Path) -> None:
    val = {"a": str(bars(tmp_path / "a")), "b": str(bars(tmp_path / "b"))}
    settings = grid((1.0,), (1.0, 0.3), (None,))
    logs: list[str] = []
    res = tune(
        VINES,
        str(bundled.guide_path()),
        val,
        tmp_path / "t.onnx",
        tmp_path / "w",
        settings,
        k=2,
        repeats=1,
        workers=1,
        log=logs.append,
    )
    rows = list(csv.DictReader((tmp_path / "w" / "tune.csv").open()))
    assert [r["setting"] for r in rows] == ["T1_Tc1_essnone", "T1_Tc0.3_essnone"]
    means = [float(r["mean"]) for r in rows]
    assert res["best"] == settings[int(np.argmax(means))]
    for r in rows:
        assert float(r["mean"]) == pytest.approx((float(r["a"]) + float(r["b"])) / 2, abs=2e-4)
    program = bundled.bundled_program()
    assert Guide.load(tmp_path / "t.onnx", program).settings == res["best"]
    assert "**" in res["table"] and "| a | b | mean |" in res["table"]
    # unguided SMC at the same N as the baseline, and the spread over targets
    base = res["table"].splitlines()[-1]
    assert base.startswith("| unguided SMC, N = 10 | | | ") and base.count(" +- ") == 2
    for r in rows:
        assert float(r["a_ci95"]) >= 0 and f"{float(r['a']):.3f} +- " in res["table"]
    assert logs[0] == "held-out: 12 runs, 12 to do"  # 2 settings + unguided, 2 x 2 targets
    logs.clear()
    again = tune(
        VINES,
        str(bundled.guide_path()),
        val,
        tmp_path / "t2.onnx",
        tmp_path / "w",
        settings,
        k=2,
        repeats=1,
        workers=1,
        log=logs.append,
    )
    assert logs == ["held-out: 12 runs, 0 to do"] and again["rows"] == res["rows"]


def _scores(res: dict) -> list[tuple]:
    return [(r["setting"], r["a"], r["mean"]) for r in res["rows"]]


def test_an_interrupted_tune_resumes_where_it_stopped(tmp_path: Path, monkeypatch) -> None:
    """Finding 4: every run is in heldout_runs.csv as soon as it ends, so a tune stopped
    after 4 of 6 runs does only the last 2 when run again, and chooses as an uninterrupted
    tune does."""
    val = {"a": str(bars(tmp_path / "a"))}
    settings = grid((1.0,), (1.0, 0.3), (None,))
    guide = str(bundled.guide_path())
    kw = dict(k=2, repeats=1, workers=1)
    whole = tune(
        VINES, guide, val, tmp_path / "t.onnx", tmp_path / "w", settings, log=lambda _m: None, **kw
    )
    interrupt_after(monkeypatch, 4)
    with pytest.raises(KeyboardInterrupt):
        tune(
            VINES,
            guide,
            val,
            tmp_path / "t2.onnx",
            tmp_path / "w2",
            settings,
            log=lambda _m: None,
            **kw,
        )
    monkeypatch.undo()  # runs go on as usual
    logs: list[str] = []
    again = tune(
        VINES, guide, val, tmp_path / "t2.onnx", tmp_path / "w2", settings, log=logs.append, **kw
    )
    assert logs == ["held-out: 6 runs, 2 to do"]
    assert _scores(again) == _scores(whole) and again["best"] == whole["best"]


def test_a_tune_killed_by_sigterm_keeps_its_finished_runs(tmp_path: Path, monkeypatch) -> None:
    """Finding 4 as reported: `ngpmc tune` killed by SIGTERM in the middle of its runs; run
    again, it has only the runs the killed one had not finished left to do."""
    val = bars(tmp_path / "a")
    work = tmp_path / "w"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ngpm_compiler.cli",
            "tune",
            VINES,
            str(bundled.guide_path()),
            "--validate",
            f"a={val}",
            "-o",
            str(tmp_path / "t.onnx"),
            "--work",
            str(work),
            "--choice-temperatures",
            "0.5",
            "--ess",
            "none",
            "--targets",
            "2",
            "--repeats",
            "30",
            "--workers",
            "1",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    runs = work / "heldout_runs.csv"
    deadline = time.monotonic() + 120
    while (
        time.monotonic() < deadline
        and proc.poll() is None
        and not (runs.is_file() and runs.read_text().count("\n") > 3)
    ):
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGTERM)
    proc.communicate(timeout=60)
    assert runs.is_file(), "no run was kept"
    done = len(read_runs(runs, HELDOUT_FIELDS, log=lambda _m: None))
    assert 3 <= done < 120
    logs: list[str] = []

    def stop(*_a, **_k):
        raise KeyboardInterrupt  # the count of runs to do is all this test needs

    monkeypatch.setattr(heldout, "run_tasks", stop)
    with pytest.raises(KeyboardInterrupt):
        tune(
            VINES,
            str(bundled.guide_path()),
            {"a": str(val)},
            tmp_path / "t.onnx",
            work,
            grid((1.0,), (0.5,), (None,)),
            k=2,
            repeats=30,
            workers=1,
            log=logs.append,
        )
    assert logs == [f"held-out: 120 runs, {120 - done} to do"]


def test_a_reused_work_folder_never_serves_stale_runs(tmp_path: Path) -> None:
    """Finding 4: a work folder reused with another guide, or after a validation image
    changed under the same name, runs what changed and chooses as a fresh tune does."""
    val = {"a": str(bars(tmp_path / "a"))}
    settings = grid((1.0,), (1.0, 0.3), (None,))
    other = perturbed_guide(bundled.guide_path(), tmp_path / "other.onnx")
    kw = dict(k=2, repeats=1, workers=1)
    quiet = lambda _m: None  # noqa: E731
    tune(
        VINES,
        str(bundled.guide_path()),
        val,
        tmp_path / "t.onnx",
        tmp_path / "w",
        settings,
        log=quiet,
        **kw,
    )
    logs: list[str] = []
    res = tune(
        VINES, str(other), val, tmp_path / "t.onnx", tmp_path / "w", settings, log=logs.append, **kw
    )
    assert logs == ["held-out: 6 runs, 4 to do"]  # the unguided runs are the same
    fresh = tune(
        VINES, str(other), val, tmp_path / "f.onnx", tmp_path / "f", settings, log=quiet, **kw
    )
    assert _scores(res) == _scores(fresh)
    assert (tmp_path / "w" / "source.txt").read_text().endswith(f" {other}\n")
    t0 = Path(val["a"]) / "t0.png"
    mask = np.zeros((50, 50), bool)
    mask[10:40, 10:14] = True  # a thin bar where the old target had its stem
    save_target(Target(mask, (0.24, 0.78, 0.0, -1.0), "t0"), t0)
    logs.clear()
    res = tune(
        VINES, str(other), val, tmp_path / "t.onnx", tmp_path / "w", settings, log=logs.append, **kw
    )
    assert logs == ["held-out: 6 runs, 3 to do"]  # t0: unguided and 2 settings
    fresh = tune(
        VINES, str(other), val, tmp_path / "f2.onnx", tmp_path / "f2", settings, log=quiet, **kw
    )
    assert _scores(res) == _scores(fresh)


def test_the_table_counts_the_targets_it_ran() -> None:
    rows = [
        {
            "setting": "s",
            "temperature": 1.0,
            "choice_temperature": 1.0,
            "ess_threshold": None,
            "a": 0.5,
            "b": 0.25,
            "mean": 0.375,
        }
    ]
    table = tune_table(rows, ["a", "b"], "s", {"a": 12, "b": 12}, 5)
    assert table.startswith("Guided SMC, N = 10, 12 targets per set, 5 runs each")
    table = tune_table(rows, ["a", "b"], "s", {"a": 12, "b": 36}, 5)
    assert table.startswith("Guided SMC, N = 10, targets per set: a 12, b 36, 5 runs each")


def test_cli_tune_and_its_errors(tmp_path: Path, capsys) -> None:
    val = bars(tmp_path / "v")
    guide = str(bundled.guide_path())
    out = tmp_path / "g.onnx"
    code = main(
        [
            "tune",
            VINES,
            guide,
            "--validate",
            f"v={val}",
            "-o",
            str(out),
            "--choice-temperatures",
            "0.5",
            "--ess",
            "0.5",
            "--targets",
            "5",
            "--repeats",
            "1",
            "--workers",
            "1",
        ]
    )
    text = capsys.readouterr().out
    assert code == 0 and out.is_file()
    assert "N = 10, 2 targets per set, 1 runs each" in text  # all the set has, not 5
    assert f"{out}: proposes with T=1,Tc=0.5,ess=0.5 (runs in {tmp_path / 'g_tune'})" in text
    assert Guide.load(out, bundled.bundled_program()).settings == ProposalSettings(1.0, 0.5, 0.5)
    for args, want in ((["--validate", f"v={tmp_path / 'nope'}"], "nope: no such directory"),):
        code = main(["tune", VINES, guide, "-o", str(tmp_path / "x.onnx"), *args])
        err = capsys.readouterr().err
        assert code != 0 and want in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1, err
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "tune",
                VINES,
                guide,
                "-o",
                str(tmp_path / "x.onnx"),
                "--validate",
                f"v={val}",
                "--ess",
                "often",
            ]
        )
    assert exc.value.code == 2
    for args, want in (
        (["--targets", "0"], "argument --targets: must be from 1"),
        (["--choice-temperatures", "0"], "temperature must be a number in"),
    ):
        with pytest.raises(SystemExit, match="2"):
            main(
                [
                    "tune",
                    VINES,
                    guide,
                    "-o",
                    str(tmp_path / "x.onnx"),
                    "--validate",
                    f"v={val}",
                    *args,
                ]
            )
        assert want in capsys.readouterr().err
    code = main(
        [
            "tune",
            VINES,
            str(val / "t0.png"),
            "-o",
            str(tmp_path / "x.onnx"),
            "--validate",
            f"v={val}",
        ]
    )
    err = capsys.readouterr().err
    assert code != 0 and "t0.png" in err and "Traceback" not in err


def test_cli_tune_counts_the_targets_of_a_set_of_12(tmp_path: Path, monkeypatch, capsys) -> None:
    """Issue 23: `ngpmc tune` printed "36 targets per set" (the --targets default) for sets
    of 12. The runs are faked (similarity 0.5): only the count is checked."""
    from ngpm_compiler.evaluation.runs import RunResult

    val = bars(tmp_path / "v", n=12)

    def fake_runs(grammar, targets, guides, tasks, on_result=None, **_kw):
        for t in tasks:
            on_result(RunResult(t, targets[t.dataset][t.target].name, 0.5, 0.01, []))

    monkeypatch.setattr(heldout, "run_tasks", fake_runs)
    assert (
        main(
            [
                "tune",
                VINES,
                str(bundled.guide_path()),
                "--validate",
                f"v={val},w={val}",
                "-o",
                str(tmp_path / "g.onnx"),
                "--choice-temperatures",
                "0.5",
                "--ess",
                "none",
                "--repeats",
                "1",
            ]
        )
        == 0
    )
    (head,) = [x for x in capsys.readouterr().out.splitlines() if x.startswith("Guided")]
    assert head.startswith("Guided SMC, N = 10, 12 targets per set, 1 runs each")


def test_cli_tune_under_the_circuit_likelihood(tmp_path: Path, capsys, monkeypatch) -> None:
    """--likelihood circuit: no validation sets; guided SMC on blank canvases scored by
    equation 2's argument, which is what tune.csv holds per setting."""
    from ngpm_runtime import warmup

    monkeypatch.setattr(warmup, "cache_is_cold", lambda: False)  # no note on stderr
    guide = str(bundled.guide_path())
    out = tmp_path / "c.onnx"
    args = ["tune", VINES, guide, "-o", str(out), "--likelihood", "circuit"]
    small = ["--choice-temperatures", "1,0.3", "--ess", "none", "--targets", "2"]
    assert main([*args, *small, "--repeats", "1", "--workers", "1"]) == 0
    text = capsys.readouterr().out
    assert (
        "N = 10, 2 targets per set, 1 runs each: mean over targets of the median circuit " in text
    )
    assert f"{out}: proposes with T=1,Tc=" in text
    with open(tmp_path / "c_tune" / "heldout_runs.csv") as fh:
        runs = list(csv.DictReader(fh))
    assert {r["dataset"] for r in runs} == {"circuit"}
    assert {r["target"] for r in runs} == {"circuit_00", "circuit_01"}
    # each run's score is the circuit score of its best particle, as grow reports it
    program = bundled.bundled_program()
    r = next(r for r in runs if r["model"] == "unguided")
    res = grow(program, None, None, int(r["n"]), int(r["seed"]), "circuit")
    assert float(r["similarity"]) == pytest.approx(res.similarity, abs=1e-6)
    assert res.similarity > 0
    for argv, want in (
        (
            [*args, "--validate", f"v={tmp_path}"],
            "circuit likelihood has no targets: drop --validate",
        ),
        (["tune", VINES, guide, "-o", str(out)], "the shape likelihood needs --validate"),
    ):
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert want in err and len(err.strip().splitlines()) == 1, err
