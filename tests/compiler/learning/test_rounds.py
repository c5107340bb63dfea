"""Guided traces (expert iteration's teacher) and the round loop on a tiny configuration."""

from __future__ import annotations

import shutil
from dataclasses import replace

import numpy as np
import pytest
from fixtures.guides import perturbed_guide
from ngpm_runtime import bundled
from ngpm_runtime.grow import grow
from ngpm_runtime.image.targets import save_target
from ngpm_runtime.inference.guide import Guide, ProposalSettings
from ngpm_runtime.inference.smc import SMCOptions, TraceRecording, replay, smc
from repo_paths import REPO

from ngpm_compiler.cli import main
from ngpm_compiler.learning.rounds import (
    JOB_STRIDE,
    RoundsConfig,
    expert_iteration,
    merge_traces,
    train_config,
    warm_init,
)
from ngpm_compiler.learning.shards import TraceError
from ngpm_compiler.learning.trace_data import load_traces
from ngpm_compiler.learning.trace_jobs import run_job
from ngpm_compiler.learning.traces import TraceConfig, generate_traces
from ngpm_compiler.learning.train import load_model

GRAMMAR = str(REPO / "grammars" / "vines.lsys")


def test_guided_trace_replays_to_the_same_primitives(vines, vines_guide):
    program, guide, targets = vines, vines_guide, bundled.demo_targets()
    target = targets[0]
    trace, n_prims = run_job(program, target, seed=3, particles=8, guide=guide)
    values = [(s, v) for s, _, v in trace]
    again = replay(
        program,
        values,
        start=target.start_pose(program.viewport),
        canvas_size=target.size,
        target_mask=target.mask,
    )
    assert len(again.primitives) == n_prims > 0
    assert all(f is not None and np.isfinite(f).all() for _, f, _ in trace)


def test_guided_smc_weights_are_exact(vines, vines_guide):
    """Guided SMC charges each particle its prior density (not the guide's): the best
    particle's log prior is the prior density of its values, as a replay computes it."""
    program, guide, targets = vines, vines_guide, bundled.demo_targets()
    target = targets[1]
    res = grow(program, target, guide, 6, seed=1, trace=TraceRecording.VALUES)
    best = res.smc.best
    values = [(s, v) for s, _, v in best.trace]
    again = replay(
        program,
        values,
        start=target.start_pose(program.viewport),
        canvas_size=target.size,
        target_mask=target.mask,
    )
    assert again.primitives == best.primitives
    assert best.log_prior == pytest.approx(again.log_prior, rel=1e-9, abs=1e-9)
    # without likelihood or resampling, a particle's weight is log prior - log proposal
    one = smc(
        program,
        None,
        1,
        guide,
        options=SMCOptions(
            ess_from_proposal=True,
            seed=2,
            start=target.start_pose(program.viewport),
            canvas_size=target.size,
            target_mask=target.mask,
        ),
    )
    assert np.isfinite(one.log_weights[0]) and one.log_weights[0] != 0.0
    prior_only = smc(
        program, None, 1, options=SMCOptions(seed=2, start=target.start_pose(program.viewport))
    )
    assert prior_only.log_weights[0] == 0.0


def _targets(tmp_path, n=2):
    d = tmp_path / "targets"
    d.mkdir()
    for t in bundled.demo_targets()[:n]:
        save_target(t, d / f"{t.name}.png")
    return d


def test_guided_traces_directory_records_the_guide(tmp_path):
    d = _targets(tmp_path)
    guide = str(bundled.guide_path())
    cfg = TraceConfig(grammar=GRAMMAR, targets=str(d), n=2, particles=5, workers=1, guide=guide)
    m = generate_traces(cfg, tmp_path / "traces", progress=False)
    assert m["kept"] == 2 and len(m["key"]["guide"]) == 64
    unguided = TraceConfig(grammar=GRAMMAR, targets=str(d), n=1, particles=5, workers=1)
    assert generate_traces(unguided, tmp_path / "u", progress=False)["key"]["guide"] is None
    ts = merge_traces([load_traces(tmp_path / "traces"), load_traces(tmp_path / "u")])
    assert len(ts.kept_jobs) == 3 and (ts.kept_jobs >= JOB_STRIDE).sum() == 1
    # `ngpmc train` takes several directories
    out = tmp_path / "m.pt"
    assert (
        main(["train", f"{tmp_path / 'traces'},{tmp_path / 'u'}", "-o", str(out), "--epochs", "1"])
        == 0
    )
    assert load_model(out).summary["traces"] == 3
    # traces of other feature layouts (another feature definition) do not mix
    other = load_traces(tmp_path / "u")
    other.layouts = {
        i: {**lay, "context": slice(lay["context"].start, lay["context"].stop - 1)}
        for i, lay in other.layouts.items()
    }
    with pytest.raises(TraceError, match="traces with different feature layouts cannot be merged$"):
        merge_traces([load_traces(tmp_path / "traces"), other])


def small_rounds(tmp_path, d, rounds: int, val_targets: int) -> RoundsConfig:
    """Rounds of 2 traces of 5 particles from the bundled guide, validated on `d`."""
    return RoundsConfig(
        grammar=GRAMMAR,
        targets=[str(d)],
        validation={"v": str(d)},
        out=str(tmp_path / "ei"),
        rounds=rounds,
        n=2,
        particles=5,
        init_guide=str(bundled.guide_path()),
        val_targets=val_targets,
        val_repeats=1,
        epochs=1,
        workers=1,
        mirror=False,
    )


def test_round_loop_keeps_the_best_round(tmp_path, vines):
    d = _targets(tmp_path)
    cfg = small_rounds(tmp_path, d, rounds=2, val_targets=1)
    rows = expert_iteration(cfg, log=lambda _m: None)
    assert [r["round"] for r in rows] == [0, 1, 2]
    assert rows[2]["traces"] == 4  # round 2 trains on both rounds' traces
    best = max(rows, key=lambda r: r["validation"])
    assert (tmp_path / "ei" / "best.onnx").read_bytes() == open(best["guide"], "rb").read()
    assert (tmp_path / "ei" / "rounds.csv").is_file()
    logs: list[str] = []
    again = expert_iteration(cfg, log=logs.append)  # resumed: nothing recorded or trained
    assert [r["validation"] for r in again] == [r["validation"] for r in rows]
    assert sum("reusing" in m for m in logs) == 2
    # another feature set: the rounds' guides are trained anew, with the context columns
    logs.clear()
    ctx = expert_iteration(replace(cfg, feature_set="all+context"), log=logs.append)
    assert not any("reusing" in m for m in logs)
    assert all(Guide.load(r["guide"], vines).feature_context for r in ctx[1:])
    # warm start: round 2 starts from round 1's weights, round 1 from none (round 0 is a file)
    warm = replace(cfg, feature_set="all+context", warm_start=True)
    assert warm_init(warm, 1) is None and warm_init(cfg, 2) is None
    init = warm_init(warm, 2)
    assert init is not None and init.feature_set == "all+context"  # ctx's round 1
    short = replace(warm, warm_patience=2)
    assert train_config(short, warm=True).patience == 2
    assert train_config(short).patience == train_config(warm, warm=True).patience == cfg.patience


def test_cli_traces_with_a_guide(tmp_path, capsys):
    from ngpm_compiler.cli import main

    d = _targets(tmp_path, n=1)
    out = tmp_path / "t"
    code = main(
        [
            "traces",
            GRAMMAR,
            "--targets",
            str(d),
            "-n",
            "1",
            "--particles",
            "4",
            "--workers",
            "1",
            "-o",
            str(out),
            "--guide",
            str(bundled.guide_path()),
        ]
    )
    assert code == 0 and "1 traces kept" in capsys.readouterr().out
    assert (
        main(
            [
                "traces",
                GRAMMAR,
                "--targets",
                str(d),
                "-n",
                "1",
                "-o",
                str(tmp_path / "x"),
                "--guide",
                str(tmp_path / "missing.onnx"),
            ]
        )
        != 0
    )


def test_cli_iterate_checks_its_inputs(tmp_path, capsys):
    from ngpm_compiler.cli import main

    code = main(
        [
            "iterate",
            GRAMMAR,
            "--targets",
            str(tmp_path / "none"),
            "--validate",
            f"v={tmp_path}",
            "-o",
            str(tmp_path / "ei"),
        ]
    )
    assert code != 0 and "no such file or directory" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="2"):  # argparse refuses it
        main(
            [
                "iterate",
                GRAMMAR,
                "--targets",
                str(tmp_path),
                "--validate",
                f"v={tmp_path}",
                "-o",
                str(tmp_path / "ei"),
                "--rounds",
                "0",
            ]
        )


def test_a_resumed_iteration_scores_a_changed_round_anew(tmp_path):
    """Finding 4: a round whose guide changed since it was scored (retrained with more
    traces, say) is scored again on resume, not served its old score from validation/;
    the rows and best.onnx are a fresh scoring's."""
    d = _targets(tmp_path)
    cfg = small_rounds(tmp_path, d, rounds=1, val_targets=2)
    first = expert_iteration(cfg, log=lambda _m: None)
    guide = tmp_path / "ei" / "round_1" / "guide.onnx"
    perturbed_guide(bundled.guide_path(), guide)  # as if round 1 had been trained again
    shutil.copytree(tmp_path / "ei", tmp_path / "fresh")
    (tmp_path / "fresh" / "validation" / "heldout_runs.csv").unlink()
    logs: list[str] = []
    resumed = expert_iteration(cfg, log=logs.append)
    fresh = expert_iteration(replace(cfg, out=str(tmp_path / "fresh")), log=lambda _m: None)
    assert "round_1: validation similarity" in logs[-2]
    assert resumed[1]["validation"] != first[1]["validation"]
    assert [r["validation"] for r in resumed] == [r["validation"] for r in fresh]
    assert (tmp_path / "ei" / "best.onnx").read_bytes() == (
        tmp_path / "fresh" / "best.onnx"
    ).read_bytes()


def test_cli_iterate_refuses_an_initial_guide_of_another_grammar(tmp_path):
    """It used to hang: the validation pool's workers failed to load it, forever."""
    import os
    import subprocess
    import sys

    from fixtures.datasets import CHAIN, make_dataset

    data = make_dataset(tmp_path / "data", 2)
    guide = bundled.guide_path()
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "ngpm_compiler.cli",
            "iterate",
            CHAIN,
            "--targets",
            str(data),
            "--validate",
            f"v={data}",
            "-o",
            str(tmp_path / "ei"),
            "--init-guide",
            str(guide),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{REPO / 'runtime'}"},
    )
    assert proc.returncode == 1
    assert (
        proc.stderr.startswith(f"ngpmc: error: {guide}: guide was trained for grammar 'vines'")
        and len(proc.stderr.strip().splitlines()) == 1
    )
    assert not (tmp_path / "ei").exists()


def test_rounds_compare_under_equal_proposal_settings(tmp_path, monkeypatch):
    """Issue 23: an initial guide tuned by `ngpmc tune` was scored with its tuned settings
    and every new round untuned, so round 0 (0.583) was kept over a round 1 that was better
    under equal settings. Here scoring is faked: a guide's score is its networks' quality
    plus 0.083 when it proposes with tuned settings; round 0 is now scored untuned."""
    from ngpm_compiler.evaluation import heldout
    from ngpm_compiler.learning import rounds
    from ngpm_compiler.learning.tune import with_settings

    program = bundled.bundled_program()
    tuned = ProposalSettings(1.0, 0.3, 0.3)
    init = with_settings(bundled.guide_path(), tmp_path / "init.onnx", tuned)
    round_1 = with_settings(
        perturbed_guide(bundled.guide_path(), tmp_path / "new.onnx"),
        tmp_path / "round_1.onnx",
        ProposalSettings(),
    )  # as trained
    quality = {"round_0": 0.50, "round_1": 0.544}
    scored: dict[str, ProposalSettings] = {}
    teachers: list[str | None] = []

    def fake_heldout(out, grammar, sets, guides, **kw):
        ((name, path),) = guides.items()
        scored[name] = Guide.load(path, program).settings
        bonus = 0.083 if scored[name] != ProposalSettings() else 0.0
        return {
            "summary": [
                {"model": name, "n": kw["guided_n"], "mean_similarity": quality[name] + bonus}
            ]
        }

    def fake_record(cfg, r, guide, log):
        teachers.append(guide)
        return []

    monkeypatch.setattr(heldout, "run_heldout", fake_heldout)
    monkeypatch.setattr(rounds, "record_round", fake_record)
    monkeypatch.setattr(
        rounds,
        "train_round",
        lambda cfg, r, dirs, log: (str(round_1), {"traces": 2, "val_nll": 1.0}),
    )
    cfg = RoundsConfig(
        grammar=GRAMMAR,
        targets=[str(tmp_path)],
        validation={"v": str(tmp_path)},
        out=str(tmp_path / "ei"),
        rounds=1,
        init_guide=str(init),
        workers=1,
    )
    logs: list[str] = []
    rows = expert_iteration(cfg, log=logs.append)
    assert scored == {"round_0": ProposalSettings(), "round_1": ProposalSettings()}
    assert [r["validation"] for r in rows] == [0.5, 0.544]
    assert rows[0]["teacher"] == "initial guide (scored untuned)"
    assert rows[0]["guide"] == str(init) and teachers == [str(init)]  # the tuned file teaches
    assert (tmp_path / "ei" / "best.onnx").read_bytes() == round_1.read_bytes()
    assert "proposes with T=1,Tc=0.3,ess=0.3 (ngpmc tune); scored with the default" in logs[0]
    # an untuned initial guide is scored as it is, with no copy
    plain = with_settings(bundled.guide_path(), tmp_path / "plain.onnx", ProposalSettings())
    rows = expert_iteration(
        replace(cfg, init_guide=str(plain), out=str(tmp_path / "p")), log=lambda _m: None
    )
    assert rows[0]["teacher"] == "initial guide"
    assert not (tmp_path / "p" / "round_0" / "untuned.onnx").exists()


def test_cli_iterate_under_the_circuit_likelihood(tmp_path, capsys):
    """--likelihood circuit: rounds on blank canvases, scored by equation 2's argument;
    --targets or --validate with it, or the shape likelihood without them: one line each."""
    import json

    from fixtures.datasets import CHAIN

    out = tmp_path / "ei"
    argv = ["iterate", CHAIN, "--likelihood", "circuit", "-o", str(out)]
    tiny = ["--rounds", "1", "-n", "2", "--particles", "6", "--unguided-particles", "6"]
    tiny += ["--val-targets", "1", "--val-repeats", "1", "--epochs", "1", "--workers", "1"]
    assert main([*argv, *tiny]) == 0
    assert "| 1 | unguided N=6 |" in capsys.readouterr().out
    (manifest,) = (out / "round_1").glob("traces_*/manifest.json")
    key = json.loads(manifest.read_text())["key"]
    assert key["likelihood"] == "circuit" and key["targets"] == ["circuit"]
    for extra, want in (
        (["--targets", str(tmp_path)], "the circuit likelihood has no targets: drop --targets"),
        (["--validate", f"v={tmp_path}"], "the circuit likelihood has no targets: drop --valid"),
    ):
        assert main([*argv, *extra]) == 1
        err = capsys.readouterr().err
        assert want in err and len(err.strip().splitlines()) == 1, err
    assert main(["iterate", CHAIN, "-o", str(out)]) == 1
    assert "the shape likelihood needs --targets" in capsys.readouterr().err
