"""`ngpmc tune`: the settings grid, settings in the guide's metadata (read by Guide.load and
grow), the validation run (cached, resumable) and the CLI's errors."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import onnx
import pytest
from ngpm_runtime import bundled
from ngpm_runtime.errors import GuideError, NgpmError
from ngpm_runtime.grow import grow
from ngpm_runtime.image.targets import Target, save_target
from ngpm_runtime.inference.guide import PROPOSAL_KEY, Guide, ProposalSettings
from repo_paths import REPO

from ngpm_compiler.cli import main
from ngpm_compiler.learning.tune import grid, name, tune, with_settings

VINES = str(REPO / "grammars" / "vines.lsys")


def bars(directory: Path, n: int = 2) -> Path:
    directory.mkdir(parents=True)
    for i in range(n):
        mask = np.zeros((50, 50), bool)
        mask[8:44, 18 + 4 * i:26 + 4 * i] = True
        mask[8:16, 10:40] = True
        save_target(Target(mask, (0.45, 0.9, 0.0, -1.0), f"t{i}"), directory / f"t{i}.png")
    return directory


def test_grid_puts_the_untouched_networks_first_and_names_settings() -> None:
    got = grid((1.0,), (0.5, 1.0), (0.5, None))
    assert [name(s) for s in got] == ["T1_Tc0.5_ess0.5", "T1_Tc0.5_essnone",
                                      "T1_Tc1_ess0.5", "T1_Tc1_essnone"]
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
    np.testing.assert_allclose(q, p ** (1 / 0.3) / (p ** (1 / 0.3)).sum(1, keepdims=True),
                               rtol=1e-6)
    assert Guide.load(out, program, settings=ProposalSettings()).settings == ProposalSettings()
    # grow resamples by the guide's ESS threshold: fewer resamples than steps
    target = Target(np.pad(np.ones((30, 12), bool), ((10, 10), (19, 19))), (0.5, 0.8, 0, -1))
    tuned = grow(program, target, g, 10, seed=1).smc
    every = grow(program, target, plain, 10, seed=1).smc
    assert tuned.info["resamples"] < 0.8 * tuned.steps
    assert every.info["resamples"] > 0.8 * every.steps


def test_corrupt_settings_are_a_one_line_error(tmp_path: Path) -> None:
    proto = onnx.load(str(bundled.guide_path()))
    onnx.helper.set_model_props(proto, {**{p.key: p.value for p in proto.metadata_props},
                                        PROPOSAL_KEY: '{"temperature": -1}'})
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(proto.SerializeToString())
    with pytest.raises(GuideError, match="bad.onnx: guide proposal settings are corrupt"):
        Guide.load(bad, bundled.bundled_program())


def test_tune_picks_the_best_setting_and_resumes(tmp_path: Path) -> None:
    val = {"a": str(bars(tmp_path / "a")), "b": str(bars(tmp_path / "b"))}
    settings = grid((1.0,), (1.0, 0.3), (None,))
    logs: list[str] = []
    res = tune(VINES, str(bundled.guide_path()), val, tmp_path / "t.onnx", tmp_path / "w",
               settings, k=2, repeats=1, workers=1, log=logs.append)
    rows = list(csv.DictReader((tmp_path / "w" / "tune.csv").open()))
    assert [r["setting"] for r in rows] == ["T1_Tc1_essnone", "T1_Tc0.3_essnone"]
    means = [float(r["mean"]) for r in rows]
    assert res["best"] == settings[int(np.argmax(means))]
    for r in rows:
        assert float(r["mean"]) == pytest.approx((float(r["a"]) + float(r["b"])) / 2, abs=2e-4)
    program = bundled.bundled_program()
    assert Guide.load(tmp_path / "t.onnx", program).settings == res["best"]
    assert "**" in res["table"] and "| a | b | mean |" in res["table"]
    assert logs[0] == "held-out: 12 runs, 12 to do"  # 2 settings + unguided, 2 x 2 targets
    logs.clear()
    again = tune(VINES, str(bundled.guide_path()), val, tmp_path / "t2.onnx", tmp_path / "w",
                 settings, k=2, repeats=1, workers=1, log=logs.append)
    assert logs == ["held-out: 12 runs, 0 to do"] and again["rows"] == res["rows"]
    other = tmp_path / "other.onnx"
    other.write_bytes((tmp_path / "t.onnx").read_bytes())
    with pytest.raises(NgpmError, match="tuned another guide before"):
        tune(VINES, str(other), val, tmp_path / "t3.onnx", tmp_path / "w", settings, k=2,
             repeats=1, workers=1, log=logs.append)


def test_cli_tune_and_its_errors(tmp_path: Path, capsys) -> None:
    val = bars(tmp_path / "v")
    guide = str(bundled.guide_path())
    out = tmp_path / "g.onnx"
    code = main(["tune", VINES, guide, "--validate", f"v={val}", "-o", str(out),
                 "--choice-temperatures", "0.5", "--ess", "0.5", "--targets", "2",
                 "--repeats", "1", "--workers", "1"])
    text = capsys.readouterr().out
    assert code == 0 and out.is_file()
    assert f"{out}: proposes with T=1,Tc=0.5,ess=0.5 (runs in {tmp_path / 'g_tune'})" in text
    assert Guide.load(out, bundled.bundled_program()).settings == ProposalSettings(1.0, 0.5, 0.5)
    for args, want in (
        (["--validate", f"v={tmp_path / 'nope'}"], "nope: no such directory"),
    ):
        code = main(["tune", VINES, guide, "-o", str(tmp_path / "x.onnx"), *args])
        err = capsys.readouterr().err
        assert code != 0 and want in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1, err
    with pytest.raises(SystemExit) as exc:
        main(["tune", VINES, guide, "-o", str(tmp_path / "x.onnx"), "--validate", f"v={val}",
              "--ess", "often"])
    assert exc.value.code == 2
    for args, want in ((["--targets", "0"], "argument --targets: must be from 1"),
                       (["--choice-temperatures", "0"], "temperature must be a number in")):
        with pytest.raises(SystemExit, match="2"):
            main(["tune", VINES, guide, "-o", str(tmp_path / "x.onnx"), "--validate",
                  f"v={val}", *args])
        assert want in capsys.readouterr().err
    code = main(["tune", VINES, str(val / "t0.png"), "-o", str(tmp_path / "x.onnx"),
                 "--validate", f"v={val}"])
    err = capsys.readouterr().err
    assert code != 0 and "t0.png" in err and "Traceback" not in err
