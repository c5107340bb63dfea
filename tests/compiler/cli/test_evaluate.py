"""`ngpmc eval --quick` end to end in a temp dir: every output exists and is well formed."""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from repo_paths import REPO

from ngpm_compiler.cli import main
from ngpm_compiler.evaluation.runs import RUN_FIELDS, SUMMARY_FIELDS

PNGS = (
    "fig4a_similarity.png",
    "fig4b_time.png",
    "fig5a_mixture.png",
    "fig5b_trainset.png",
    "grid_glyphs.png",
    "grid_silhouettes.png",
    "circuit.png",
    "chain.png",
)
MODELS = {"unguided", "const", "local", "local+target", "all", "all_k1"}


def _csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("eval") / "results"
    cwd = os.getcwd()
    os.chdir(REPO)  # the default grammar paths are relative to the repository root
    try:
        assert main(["eval", "--quick", "-o", str(out)]) == 0
    finally:
        os.chdir(cwd)
    return out


def test_quick_writes_every_file(quick: Path) -> None:
    """Every output exists and holds something: tables have a header and rows, the
    settings parse and say --quick, the Markdown files are not empty."""
    for name in (
        *PNGS,
        "README.md",
        "report.md",
        "settings.json",
        "shape_runs.csv",
        "shape_summary.csv",
        "speedup.csv",
        "trainset.csv",
        "models.csv",
        "grids.csv",
        "circuit_runs.csv",
        "chain_runs.csv",
    ):
        path = quick / name
        assert path.is_file() and path.stat().st_size > 0, name
        if name.endswith(".csv"):
            rows = _csv(path)
            assert rows and all(len(r) >= 2 for r in rows), name
            assert not any(None in r or None in r.values() for r in rows), name  # ragged
        elif name.endswith(".md"):
            assert len(path.read_text().strip().splitlines()) > 3, name
    settings = json.loads((quick / "settings.json").read_text())
    assert isinstance(settings, dict) and settings
    assert "quick" in json.dumps(settings)


def test_pngs_are_images_under_300kb(quick: Path) -> None:
    for name in PNGS:
        p = quick / name
        assert p.stat().st_size < 300_000, name
        with Image.open(p) as im:
            im.verify()
        with Image.open(p) as im:
            arr = np.asarray(im.convert("L"))
            assert arr.shape[0] > 100 and arr.shape[1] > 100
            assert arr.std() > 5, f"{name} looks blank"


def test_runs_csv_covers_models_targets_and_ns(quick: Path) -> None:
    rows = _csv(quick / "shape_runs.csv")
    assert tuple(rows[0]) == RUN_FIELDS
    assert MODELS <= {r["model"] for r in rows}
    assert {r["dataset"] for r in rows} == {"glyphs", "silhouettes"}
    ug = {(r["target"], int(r["n"])) for r in rows if r["model"] == "unguided"}
    assert {n for _, n in ug} == {1, 3, 6}
    for r in rows:
        assert -1.0 <= float(r["similarity"]) <= 1.0
        assert float(r["seconds"]) > 0
    # two repeats of every (model, target, N)
    keys = [(r["model"], r["target"], r["n"]) for r in rows]
    assert all(keys.count(k) == 2 for k in set(keys))


def test_summary_is_consistent_with_runs(quick: Path) -> None:
    runs = _csv(quick / "shape_runs.csv")
    summ = _csv(quick / "shape_summary.csv")
    assert tuple(summ[0]) == SUMMARY_FIELDS
    for s in summ:
        sub = [
            r
            for r in runs
            if r["model"] == s["model"]
            and r["n"] == s["n"]
            and s["dataset"] in ("all", r["dataset"])
        ]
        meds = []
        for t in sorted({r["target"] for r in sub}):
            meds.append(np.median([float(r["similarity"]) for r in sub if r["target"] == t]))
        assert float(s["mean_similarity"]) == pytest.approx(np.mean(meds), abs=1e-5)
        assert float(s["ci_low"]) <= float(s["mean_similarity"]) <= float(s["ci_high"])


def test_other_tables(quick: Path) -> None:
    speed = _csv(quick / "speedup.csv")
    assert {r["model"] for r in speed} == {"const", "local", "local+target", "all"}
    ts = _csv(quick / "trainset.csv")
    assert [int(r["traces"]) for r in ts] == sorted(int(r["traces"]) for r in ts)
    assert len(ts) >= 2
    grids = _csv(quick / "grids.csv")
    assert {r["kind"] for r in grids} == {
        "reference",
        "guided",
        "unguided_equal_n",
        "unguided_equal_time",
    }
    circ = _csv(quick / "circuit_runs.csv")
    assert {r["kind"] for r in circ} == {
        "reference",
        "guided",
        "unguided_equal_n",
        "unguided_equal_time",
    }
    chain = _csv(quick / "chain_runs.csv")
    assert {r["model"] for r in chain} == {"unguided", "guided"}
    models = {r["model"] for r in _csv(quick / "models.csv")}
    assert MODELS - {"unguided"} <= models


def test_reports_embed_figures_and_numbers(quick: Path) -> None:
    readme = (quick / "README.md").read_text()
    for name in PNGS:
        assert f"]({name})" in readme
    assert "Headline figures" in readme and "guided (all features) N = 3" in readme
    report = (quick / "report.md").read_text()
    assert "## Settings" in report and "## Guides" in report
    settings = json.loads((quick / "settings.json").read_text())
    assert settings["quick"] is True and settings["test_targets"] == {"glyphs": 1, "silhouettes": 1}


def test_report_stage_alone_reuses_csvs(quick: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (quick / "notes.md").write_text("Hand-written discussion.\n")
    monkeypatch.chdir(REPO)
    assert main(["eval", "--quick", "-o", str(quick), "--stages", "report"]) == 0
    assert "Hand-written discussion." in (quick / "README.md").read_text()


def test_bad_options_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(REPO)
    with pytest.raises(SystemExit, match="2"):  # refused by argparse, before any stage runs
        main(["eval", "--quick", "-o", str(tmp_path), "--stages", "heldout,nope"])
    err = capsys.readouterr().err
    assert "argument --stages: unknown stage nope; choose from" in err
    assert not list(tmp_path.iterdir())
    assert main(["eval", "-o", str(tmp_path), "--traces", str(tmp_path / "missing")]) != 0
    err = capsys.readouterr().err
    assert "--traces" in err and "no such file" in err
    assert main(["eval", "--quick", "-o", str(tmp_path), "--ray-address", "auto"]) != 0
    err = capsys.readouterr().err
    assert "--ray-address needs --backend ray" in err and err.count("\n") == 1


def test_eval_needs_no_repository_checkout(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """Issue #21: `ngpmc eval` found its grammars via the repository root, so an installed
    package could not run it. The vines model now comes with ngpm_runtime; the chain grammar
    is given on the command line (or found in the current folder)."""
    from ngpm_runtime import bundled

    from ngpm_compiler.cli import build_parser
    from ngpm_compiler.cli.evaluate import config_from_args

    monkeypatch.chdir(tmp_path)  # no grammars/ here
    parse = build_parser().parse_args
    cfg = config_from_args(parse(["eval", "-o", "r", "--stages", "shape,report"]))
    assert Path(cfg.shape.grammar) == bundled.sampler_path()
    assert main(["eval", "--quick", "-o", "r", "--stages", "chain"]) != 0
    err = capsys.readouterr().err
    assert "grammars/chain.lsys: no such grammar; give --chain-grammar" in err
    assert "a clone of the ngpm repository; it is not installed" in err
    assert err.count("\n") == 1
    chain = str(REPO / "grammars" / "chain.lsys")
    cfg = config_from_args(
        parse(
            [
                "eval",
                "-o",
                "r",
                "--stages",
                "chain",
                "--chain-grammar",
                chain,
                "--grammar",
                "missing.lsys",
            ]
        )
    )
    assert cfg.chain.chain_grammar == chain and cfg.chain.grammar == "missing.lsys"


def test_no_grammar_is_package_data() -> None:
    """grammars/*.lsys (chain.lsys: the chain study's) stay in the repository: no package
    holds a grammar and pyproject's package data names none."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    data = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    patterns = [p for globs in data["package-data"].values() for p in globs]
    assert not [p for p in patterns if "lsys" in p or p in ("*", "**/*")], patterns
    for package in ("ngpm_compiler", "runtime/ngpm_runtime"):
        assert not list((REPO / package).rglob("*.lsys")), package
