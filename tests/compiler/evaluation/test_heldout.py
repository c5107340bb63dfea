"""Held-out evaluation: task lists, cached runs, the table."""

from __future__ import annotations

import pytest
from fixtures.interrupt import interrupt_after
from ngpm_runtime import bundled
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.image.targets import Target, save_target
from repo_paths import REPO

from ngpm_compiler.evaluation.heldout import heldout_tasks, parse_pairs, run_heldout
from ngpm_compiler.evaluation.runs import UNGUIDED


def test_parse_pairs():
    assert parse_pairs("a=x/y, b=z") == {"a": "x/y", "b": "z"}
    assert parse_pairs("dir/g.onnx") == {"g": "dir/g.onnx"}


def test_tasks_share_seeds_between_models():
    targets = {"s": [object(), object()], "t": [object()]}
    tasks = heldout_tasks(targets, ["g"], 10, (200, 600), repeats=2)
    assert len(tasks) == 3 * 2 * (3 + 1)
    guided = {(t.dataset, t.target, t.repeat): t.seed for t in tasks if t.model == "g"}
    plain = {
        (t.dataset, t.target, t.repeat): t.seed for t in tasks if t.model == UNGUIDED and t.n == 10
    }
    assert guided == plain and all(t.n == 10 for t in tasks if t.model == "g")


def test_run_heldout_caches_runs(tmp_path):
    d = tmp_path / "set"
    d.mkdir()
    for t in bundled.demo_targets()[:2]:
        save_target(t, d / f"{t.name}.png")
    grammar = str(REPO / "grammars" / "vines.lsys")
    logs: list[str] = []
    kw = dict(k=2, repeats=1, guided_n=3, unguided_ns=(6,), workers=1, log=logs.append)
    res = run_heldout(
        tmp_path / "out", grammar, {"demo": str(d)}, {"g": str(bundled.guide_path())}, **kw
    )
    assert len(res["rows"]) == 2 * 3
    assert "| g |" in res["table"] and "unguided N=6" in res["table"]
    again = run_heldout(
        tmp_path / "out", grammar, {"demo": str(d)}, {"g": str(bundled.guide_path())}, **kw
    )
    assert logs[-1].endswith("0 to do") and len(again["rows"]) == 6


def _demo_set(directory, n=2):
    directory.mkdir()
    for t in bundled.demo_targets()[:n]:
        save_target(t, directory / f"{t.name}.png")
    return directory


def _sims(res):
    """What a held-out call measures, without the wall times."""
    return (
        [(r["model"], r["target"], r["n"], r["repeat"], r["similarity"]) for r in res["rows"]],
        [(s["model"], s["n"], s["mean_similarity"]) for s in res["summary"]],
    )


def test_an_interrupted_run_resumes_where_it_stopped(tmp_path, monkeypatch):
    """Finding 4: runs are appended one by one; a KeyboardInterrupt (or SIGTERM unwinding)
    after 2 runs keeps them, a torn last line is dropped, and the rerun does only the rest."""
    d = _demo_set(tmp_path / "set")
    grammar = str(REPO / "grammars" / "vines.lsys")
    kw = dict(k=2, repeats=1, guided_n=3, unguided_ns=(6,), workers=1)
    args = ({"demo": str(d)}, {"g": str(bundled.guide_path())})
    fresh = run_heldout(tmp_path / "fresh", grammar, *args, log=lambda _m: None, **kw)
    interrupt_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        run_heldout(tmp_path / "out", grammar, *args, log=lambda _m: None, **kw)
    monkeypatch.undo()  # runs go on as usual
    runs = tmp_path / "out" / "heldout_runs.csv"
    assert len(runs.read_text().splitlines()) == 1 + 2
    logs: list[str] = []
    res = run_heldout(tmp_path / "out", grammar, *args, log=logs.append, **kw)
    assert logs == ["held-out: 6 runs, 4 to do"] and _sims(res) == _sims(fresh)
    # a kill in the middle of a line: the torn row is run again, not read as a number
    runs.write_bytes(runs.read_bytes()[:-3])
    logs.clear()
    res = run_heldout(tmp_path / "out", grammar, *args, log=logs.append, **kw)
    assert "dropped 1 unreadable line" in logs[0] and logs[1] == "held-out: 6 runs, 1 to do"
    assert _sims(res) == _sims(fresh)
    assert len(runs.read_text().splitlines()) == 1 + 6


def test_changed_targets_are_not_served_from_the_cache(tmp_path):
    """Finding 4: a target image changed under the same name, or a target whose seed moved
    (more targets picked), is run anew; the result equals a fresh run's."""
    d = _demo_set(tmp_path / "set", n=3)
    grammar = str(REPO / "grammars" / "vines.lsys")
    kw = dict(repeats=1, guided_n=3, unguided_ns=(), workers=1)
    args: tuple = ({"demo": str(d)}, {})  # unguided runs: the targets are what changes
    quiet = lambda _m: None  # noqa: E731
    run_heldout(tmp_path / "out", grammar, *args, k=2, log=quiet, **kw)
    logs: list[str] = []
    res = run_heldout(tmp_path / "out", grammar, *args, k=3, log=logs.append, **kw)
    assert logs == ["held-out: 3 runs, 2 to do"]  # only the first target kept its seed
    assert _sims(res) == _sims(run_heldout(tmp_path / "f1", grammar, *args, k=3, log=quiet, **kw))
    image, other = sorted(d.glob("*.png"))[0], bundled.demo_targets()[3]
    save_target(Target(other.mask, other.start, image.stem), image)
    logs.clear()
    res = run_heldout(tmp_path / "out", grammar, *args, k=3, log=logs.append, **kw)
    assert logs == ["held-out: 3 runs, 1 to do"]
    assert _sims(res) == _sims(run_heldout(tmp_path / "f2", grammar, *args, k=3, log=quiet, **kw))


def test_a_runs_file_of_other_columns_is_a_one_line_error(tmp_path):
    """A heldout_runs.csv without the content-hash columns (as docs/results' copy) is
    refused in one line and left as it is, never mixed with new runs."""
    d = _demo_set(tmp_path / "set", n=1)
    grammar = str(REPO / "grammars" / "vines.lsys")
    out = tmp_path / "out"
    out.mkdir()
    old = "model,dataset,target,n,repeat,seed,similarity,seconds,primitives\n"
    old += f"unguided,demo,{bundled.demo_targets()[0].name},3,0,1,0.99,0.1,5\n"
    (out / "heldout_runs.csv").write_text(old)
    with pytest.raises(NgpmError) as err:
        run_heldout(
            out,
            grammar,
            {"demo": str(d)},
            {},
            k=1,
            repeats=1,
            guided_n=3,
            unguided_ns=(),
            workers=1,
            log=lambda _m: None,
        )
    message = str(err.value)
    assert message.startswith(f"{out / 'heldout_runs.csv'}: not a runs file (its columns")
    assert "grammar_sha" in message and "\n" not in message
    assert (out / "heldout_runs.csv").read_text() == old
