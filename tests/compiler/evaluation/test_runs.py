"""Evaluation core: statistics, time-to-threshold, speedups, task lists, runs, subsets."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from ngpm_runtime.image.targets import Target
from repo_paths import REPO

from ngpm_compiler.evaluation.runs import (
    RUN_FIELDS,
    UNGUIDED,
    grow_once,
    match_text,
    read_csv,
    run_seed,
    run_tasks,
    shape_tasks,
    speedups,
    summarize,
    t_central,
    t_interval,
    t_quantile,
    time_to_reach,
    write_csv,
)
from ngpm_compiler.experiments.extra import chain_arc
from ngpm_compiler.experiments.models import subset
from ngpm_compiler.experiments.shape import equal_time_n, pick
from ngpm_compiler.learning.trace_data import SiteData


def test_t_interval_matches_formula() -> None:
    v = np.array([0.2, 0.4, 0.5, 0.9])
    m, lo, hi = t_interval(v)
    half = 3.182446305284263 * v.std(ddof=1) / 2.0  # t(0.975, 3)
    assert m == pytest.approx(0.5)
    assert lo == pytest.approx(0.5 - half)
    assert hi == pytest.approx(0.5 + half)
    assert t_interval(np.array([0.3])) == (0.3, 0.3, 0.3)


def test_t_quantile_matches_scipy() -> None:
    """The numpy-only t quantile (no scipy in ngpm's dependencies) equals scipy's."""
    stats = pytest.importorskip("scipy.stats")
    for df in (*range(1, 60), 99, 100, 399):
        for p in (0.55, 0.9, 0.95, 0.975, 0.995, 0.9995):
            assert t_quantile(p, df) == pytest.approx(stats.t.ppf(p, df), rel=1e-11), (p, df)
        for t in (0.0, 0.3, 1.0, 2.5, 40.0):
            assert t_central(t, df) == pytest.approx(2 * stats.t.cdf(t, df) - 1, abs=1e-13)


def _row(model: str, target: str, n: int, sim: float, secs: float = 1.0) -> dict:
    return {
        "model": model,
        "dataset": "glyphs",
        "target": target,
        "n": n,
        "similarity": sim,
        "seconds": secs,
    }


def test_summarize_takes_median_per_target_then_mean() -> None:
    rows = [_row("a", "t1", 10, s) for s in (0.1, 0.5, 0.9)]  # median 0.5
    rows += [_row("a", "t2", 10, s) for s in (0.0, 0.2, 1.0)]  # median 0.2
    rows += [_row("b", "t1", 10, 0.3, 2.0)]
    out = {(r["model"], r["n"]): r for r in summarize(rows, "glyphs")}
    a = out[("a", 10)]
    assert a["targets"] == 2 and a["dataset"] == "glyphs"
    assert a["mean_similarity"] == pytest.approx(0.35)
    assert a["ci_low"] < 0.35 < a["ci_high"]
    assert out[("b", 10)]["mean_seconds"] == pytest.approx(2.0)


def test_summarize_reads_csv_strings(tmp_path: Path) -> None:
    rows = [dict(_row("a", "t1", 5, 0.25), repeat=0, seed=1, primitives=3)]
    write_csv(tmp_path / "r.csv", rows, RUN_FIELDS)
    back = read_csv(tmp_path / "r.csv")
    assert summarize(back)[0]["mean_similarity"] == pytest.approx(0.25)


def test_time_to_reach_interpolates_in_log_time() -> None:
    sims = np.array([0.2, 0.4, 0.8])
    secs = np.array([1.0, 10.0, 100.0])
    assert time_to_reach(sims, secs, 0.1) == pytest.approx(1.0)
    assert time_to_reach(sims, secs, 0.4) == pytest.approx(10.0)
    assert time_to_reach(sims, secs, 0.3) == pytest.approx(math.sqrt(10.0))
    assert time_to_reach(sims, secs, 0.6) == pytest.approx(math.sqrt(1000.0))
    assert math.isnan(time_to_reach(sims, secs, 0.9))


def test_time_to_reach_ignores_dips() -> None:
    # the curve dips at the second point: interpolation starts from the best so far
    sims = np.array([0.5, 0.3, 0.7])
    secs = np.array([1.0, 2.0, 4.0])
    assert time_to_reach(sims, secs, 0.6) == pytest.approx(2.0)


def _summary(model: str, pts: list[tuple[int, float, float]]) -> list[dict]:
    return [{"model": model, "n": n, "mean_similarity": s, "mean_seconds": t} for n, s, t in pts]


def test_speedups_and_lower_bound() -> None:
    summ = _summary(UNGUIDED, [(1, 0.1, 0.1), (10, 0.3, 1.0), (100, 0.5, 10.0)])
    summ += _summary("all", [(1, 0.3, 0.1), (10, 0.7, 1.0)])
    rows = {r["threshold"]: r for r in speedups(summ, ["all"], [0.3, 0.5, 0.7, 0.9])}
    assert rows[0.3]["speedup"] == pytest.approx(10.0)
    assert rows[0.5]["seconds"] < rows[0.5]["baseline_seconds"]
    assert rows[0.7]["bound"] == ">" and rows[0.7]["speedup"] == pytest.approx(10.0)
    assert rows[0.9]["speedup"] == ""


def test_shape_tasks_share_seeds_across_models() -> None:
    tasks = shape_tasks(["a", "b"], {"glyphs": 2, "silhouettes": 1}, [1, 5], 2, base_seed=3)
    assert len(tasks) == 2 * 3 * 2 * 2
    by = {}
    for t in tasks:
        by.setdefault((t.dataset, t.target, t.n, t.repeat), set()).add(t.seed)
    assert all(len(s) == 1 for s in by.values())
    assert len({next(iter(s)) for s in by.values()}) == len(by)  # distinct per run
    assert run_seed(3, 0, 1, 0) == run_seed(3, 0, 1, 0) != run_seed(4, 0, 1, 0)


def _disk_target() -> Target:
    yy, xx = np.mgrid[0:50, 0:50]
    mask = (xx - 25) ** 2 + (yy - 20) ** 2 < 12**2
    return Target(mask, (0.5, 0.75, 0.0, -1.0), "disk")


def test_grow_once_scores_the_best_particle(vines) -> None:
    from ngpm_runtime.image.raster import rasterize
    from ngpm_runtime.inference.likelihood import similarity

    t = _disk_target()
    sim, secs, prims = grow_once(vines, t, None, 8, seed=5)
    assert secs > 0 and prims
    img = rasterize(prims, vines.viewport, 50, 50)
    assert sim == pytest.approx(similarity(img, t.mask))
    assert grow_once(vines, t, None, 8, seed=5)[0] == sim  # deterministic given the seed


def test_run_tasks_returns_results_in_task_order() -> None:
    t = _disk_target()
    tasks = shape_tasks([UNGUIDED], {"x": 1}, [1, 4], 2)
    res = run_tasks(
        str(REPO / "grammars" / "vines.lsys"), {"x": [t]}, {}, tasks, workers=1, shuffle_seed=1
    )
    assert [r.task for r in res] == tasks
    assert all(r.target_name == "disk" and -1.0 <= r.similarity <= 1.0 for r in res)
    row = res[0].row()
    assert set(row) == set(RUN_FIELDS)


def test_subset_keeps_the_first_jobs() -> None:
    d = SiteData(
        np.zeros((6, 2), np.float32), np.arange(6.0), np.zeros((6, 2)), np.array([5, 1, 3, 1, 9, 3])
    )
    out = subset({0: d}, np.array([9, 1, 3, 5]), 2)
    assert sorted(set(out[0].jobs)) == [1, 3]
    assert list(out[0].values) == [1.0, 2.0, 3.0, 5.0]
    assert subset({0: d}, np.array([1, 3]), None)[0] is d


def test_pick_spreads_evenly() -> None:
    assert pick(list(range(10)), 3) == [0, 4, 9] or pick(list(range(10)), 3) == [0, 5, 9]
    assert pick([1, 2], 5) == [1, 2]


def test_equal_time_n() -> None:
    summ = _summary(UNGUIDED, [(10, 0.1, 0.1), (100, 0.3, 1.0)])
    assert equal_time_n(summ, 0.1, 1) == 10
    assert equal_time_n(summ, math.sqrt(0.1), 1) == round(math.sqrt(1000))
    assert equal_time_n(summ, 2.0, 1) == 200  # beyond the curve: linear in N
    assert equal_time_n(summ, 0.05, 1) == 5
    assert equal_time_n(summ, 0.001, 7) == 7


def test_chain_arc_starts_at_the_program_start() -> None:
    from ngpm_compiler.language.compile import load_grammar

    chain = load_grammar(REPO / "grammars" / "chain.lsys")
    t = chain_arc(np.random.default_rng(0), chain)
    assert t.mask.any()
    x, y, h = t.start_pose(chain.viewport)
    assert (x, y) == pytest.approx(chain.start[:2])
    assert h == pytest.approx(chain.start[2])


def test_match_text_states_a_crossing_or_a_lower_bound() -> None:
    """A baseline that reaches the guided score: its N and the ratio; one that never does:
    a lower bound from its largest N, not 'nan'."""
    ns, secs = np.array([10, 100, 1000]), np.array([0.01, 0.1, 1.2])
    assert match_text(329.4, 0.373, 0.077, ns, secs) == ("N ~ 329 in 0.373 s", "4.8x")
    assert match_text(float("nan"), float("nan"), 0.1, ns, secs) == (
        "N > 1000 (1.200 s there)",
        "> 12.0x",
    )
