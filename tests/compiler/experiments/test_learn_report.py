"""OUT/report.md of `ngpmc learn` (experiments/learn_report.py): the curve's table and plot,
and the note that replaces the plot when matplotlib is missing."""

from __future__ import annotations

import sys

from ngpm_compiler.evaluation.runs import UNGUIDED
from ngpm_compiler.experiments.learn_report import curve_lines, rounds_table


def summary() -> list[dict]:
    rows = []
    for model, sims in (("guide", {1: 0.2, 10: 0.5}), (UNGUIDED, {10: 0.1, 100: 0.3, 300: 0.6})):
        for n, sim in sims.items():
            rows.append(
                {
                    "dataset": "validation",
                    "model": model,
                    "n": n,
                    "targets": 4,
                    "mean_similarity": sim,
                    "ci_low": sim - 0.05,
                    "ci_high": sim + 0.05,
                    "mean_seconds": n / 100,
                    "median_seconds": n / 100,
                }
            )
    return rows


def test_the_curve_table_and_plot(tmp_path):
    lines = curve_lines(summary(), tmp_path)
    assert "| 10 | 0.500 | 0.100 | 0.10 | 0.10 |" in lines
    assert "| 300 |  | 0.600 |  | 3.00 |" in lines
    assert any("about 2" in x and "to match the guide at N = 10" in x for x in lines)
    assert "![similarity vs N](curve.png)" in lines
    assert (tmp_path / "curve.png").stat().st_size > 1000


def test_without_matplotlib_the_report_says_so(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib fails
    lines = curve_lines(summary(), tmp_path)
    assert lines[-1].startswith("No plot: matplotlib is missing")
    assert not (tmp_path / "curve.png").exists()


def test_no_curve_when_the_run_stopped_before_it(tmp_path):
    assert curve_lines(None, tmp_path) == [
        "The curve was not measured (the run stopped before it)."
    ]


def test_the_best_round_is_marked():
    seconds = {"traces": 60.0, "train": 5.0, "validation": 3.0}
    rows = [
        {
            "round": 0,
            "teacher": "unguided N=600",
            "traces": 10,
            "val_nll": 1.0,
            "validation": 0.2,
            "seconds": seconds,
        },
        {
            "round": 1,
            "teacher": "guided N=200 by round 0",
            "traces": 20,
            "val_nll": 0.9,
            "validation": 0.3,
            "seconds": seconds,
        },
    ]
    table = rounds_table(rows, 1)
    assert table[2].startswith("| 0 | unguided N=600 | 10 | 1.0 | 0.200 | 60 s | 5 s | 3 s |")
    assert table[3].startswith("| 1 (best) | ") and "**0.300**" in table[3]
