"""Held-out evaluation: task lists, cached runs, the table."""

from __future__ import annotations

from ngpm_runtime import bundled
from ngpm_runtime.image.targets import save_target
from repo_paths import REPO

from ngpm_compiler.experiments.evaluate import UNGUIDED
from ngpm_compiler.experiments.heldout import heldout_tasks, parse_pairs, run_heldout


def test_parse_pairs():
    assert parse_pairs("a=x/y, b=z") == {"a": "x/y", "b": "z"}
    assert parse_pairs("dir/g.onnx") == {"g": "dir/g.onnx"}


def test_tasks_share_seeds_between_models():
    targets = {"s": [object(), object()], "t": [object()]}
    tasks = heldout_tasks(targets, ["g"], 10, (200, 600), repeats=2)
    assert len(tasks) == 3 * 2 * (3 + 1)
    guided = {(t.dataset, t.target, t.repeat): t.seed for t in tasks if t.model == "g"}
    plain = {(t.dataset, t.target, t.repeat): t.seed for t in tasks
             if t.model == UNGUIDED and t.n == 10}
    assert guided == plain and all(t.n == 10 for t in tasks if t.model == "g")


def test_run_heldout_caches_runs(tmp_path):
    d = tmp_path / "set"
    d.mkdir()
    for t in bundled.demo_targets()[:2]:
        save_target(t, d / f"{t.name}.png")
    grammar = str(REPO / "grammars" / "vines.lsys")
    logs: list[str] = []
    kw = dict(k=2, repeats=1, guided_n=3, unguided_ns=(6,), workers=1, log=logs.append)
    res = run_heldout(tmp_path / "out", grammar, {"demo": str(d)},
                      {"g": str(bundled.guide_path())}, **kw)
    assert len(res["rows"]) == 2 * 3
    assert "| g |" in res["table"] and "unguided N=6" in res["table"]
    again = run_heldout(tmp_path / "out", grammar, {"demo": str(d)},
                        {"g": str(bundled.guide_path())}, **kw)
    assert logs[-1].endswith("0 to do") and len(again["rows"]) == 6
