"""benchmarks/learn_grammars.py: the multi-grammar table of `ngpmc learn` (its figures from
a summary, the page's block, the resumable run on one tiny grammar)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from repo_paths import REPO, load_script

from ngpm_compiler.evaluation.runs import UNGUIDED


def load():
    return load_script("benchmarks/learn_grammars.py")


def summary(guided: float) -> list[dict]:
    rows = [{"model": "guide", "n": 10, "mean_similarity": guided, "mean_seconds": 0.5}]
    for n, sim in ((10, 0.1), (100, 0.3), (1000, 0.5)):
        rows.append({"model": UNGUIDED, "n": n, "mean_similarity": sim, "mean_seconds": n / 100})
    return rows


def test_figures_crossing_n_and_time_ratio():
    lg = load()
    f = lg.figures(summary(0.3))
    assert f["guided"] == 0.3 and f["unguided"] == {10: 0.1, 100: 0.3, 1000: 0.5}
    assert f["match_n"] == pytest.approx(100)
    assert f["ratio"] == pytest.approx(2.0) and f["ratio_bound"] == ""  # 1 s / 0.5 s
    above = lg.figures(summary(0.7))  # unguided never gets there: bounds
    assert above["match_n"] is None
    assert above["ratio"] == pytest.approx(20.0) and above["ratio_bound"] == ">"


def test_table_and_page_block(tmp_path):
    lg = load()
    result = {
        "grammar": "bush",
        "learn_minutes": 44.5,
        "rounds": 4,
        "stopped": False,
        **lg.figures(summary(0.7)),
    }
    lines = lg.table([result], [10, 100, 1000])
    row = "| bush | 44.5 | 4 | **0.700** | 0.100 | 0.300 | 0.500 | > 1000 | >20.0x |"
    assert lines[2] == row + " varied, shapes |"  # a result without "heldout": the generic sets
    env = lg.table([{**result, "heldout": "envelopes"}], [10, 100, 1000])
    assert env[0].endswith("| held-out targets |") and env[2] == row + " envelopes |"
    worse = {**result, **lg.figures(summary(0.05))}
    assert "| **0.050** | 0.100 | 0.300 | 0.500 | <= 10 |" in lg.table([worse], [10, 100, 1000])[2]
    page = tmp_path / "page.md"
    page.write_text("# Results\n\nkept\n")
    lg.write_page(page, "first")
    lg.write_page(page, "second\ntable")
    text = page.read_text()
    assert text.startswith("# Results\n\nkept\n")
    assert "<!-- begin learn-grammars -->\nsecond\ntable\n<!-- end learn-grammars -->\n" in text
    assert "first" not in text


@pytest.mark.slow
def test_one_tiny_grammar_end_to_end_and_resumed(tmp_path, capsys):
    """`ngpmc learn` on the chain grammar with a budget of a minute, then the held-out runs;
    the second call finds the result and runs nothing."""
    lg = load()
    out, page = tmp_path / "work", tmp_path / "results" / "lg.md"
    argv = ["--budget", "75s", "--grammars", "chain", "-o", str(out), "--targets", "2"]
    argv += ["--repeats", "1", "--ns", "10,30", "--workers", "1", "--page", str(page)]
    assert lg.main(argv) == 0
    result = json.loads((out / "chain" / "result.json").read_text())
    assert result["rounds"] >= 1 and 0 < result["learn_minutes"] < 2.5
    assert set(result["unguided"]) == {"10", "30"}
    assert (out / "chain" / "learn" / "guide.onnx").is_file()
    text = page.read_text()
    assert "| chain | " in text and "<!-- end learn-grammars -->" in text
    rows = (tmp_path / "results" / "lg.csv").read_text().splitlines()
    assert rows[0] == "grammar,model,n,targets,mean_similarity,mean_seconds"
    assert any(r.startswith("chain,guide,10,4,") for r in rows)
    capsys.readouterr()
    assert lg.main(argv) == 0
    assert "chain: done before" in capsys.readouterr().out


def test_a_grammar_learned_on_envelopes_is_scored_on_held_out_envelopes(tmp_path):
    lg = load()
    learn = tmp_path / "bush" / "learn"
    learn.mkdir(parents=True)
    state = {"stages": {"targets": {"result": {"kind": "generic"}}}}
    (learn / "learn.json").write_text(json.dumps(state))
    assert lg.learned_targets(tmp_path / "bush") == "generic"
    state["stages"]["envelopes"] = {"result": {"switched": True}}
    (learn / "learn.json").write_text(json.dumps(state))
    assert lg.learned_targets(tmp_path / "bush") == "envelopes"
    sets = lg.envelope_sets(REPO / "grammars" / "bush.lsys", tmp_path / "bush", 2)
    assert list(sets) == ["envelopes_2001", "envelopes_2002"]
    index = json.loads((Path(sets["envelopes_2001"]) / "index.json").read_text())
    assert index["seed"] == 2001 and index["grammar"] == "bush.lsys" and index["count"] == 2


def test_tune_teachers_reaches_learn_and_keys_the_result(monkeypatch, tmp_path):
    """--tune-teachers is passed to `ngpmc learn` and recorded in the settings (a result
    recorded without it stays valid for runs without it)."""
    import argparse

    lg = load()
    base = dict(budget="45m", targets=12, repeats=2, ns=[10], workers=2, seed=0)
    plain = argparse.Namespace(**base, tune_teachers=False)
    tuned = argparse.Namespace(**base, tune_teachers=True)
    assert "tune_teachers" not in lg.settings(plain)
    assert lg.settings(tuned) == {**lg.settings(plain), "tune_teachers": True}
    calls = []
    monkeypatch.setattr(lg.subprocess, "call", lambda argv, **_k: calls.append(argv) or 0)
    lg.run_learn(tmp_path / "g.lsys", tmp_path / "out", tuned)
    lg.run_learn(tmp_path / "g.lsys", tmp_path / "out", plain)
    assert "--tune-teachers" in calls[0] and "--tune-teachers" not in calls[1]
