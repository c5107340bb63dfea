"""`ngpmc learn` end to end on the chain grammar (one site, 12 links) with a budget of
seconds: the guide and report, resumption after an interrupted stage, the stop at the budget
with the best guide so far, and the grammar checks before any compute."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import onnx
import pytest
from fixtures.datasets import CHAIN, make_dataset
from fixtures.grammars import EXPLODING, EXPLODING_LINE, SPECK

from ngpm_compiler.cli import main
from ngpm_compiler.experiments import learn as learn_mod
from ngpm_compiler.experiments.learn import (
    BudgetSpent,
    LearnConfig,
    LearnError,
    learn,
    train_cost,
)
from ngpm_compiler.experiments.learn_plan import MIN_TRACES, Plan

# a few seconds of work whatever the budget (the planner has its own tests): so that these
# tests do not depend on the machine's speed, they run this plan under a budget of minutes
TINY = Plan(
    budget=600.0,
    unguided_particles=20,
    guided_particles=10,
    traces=5,
    rounds=1,
    guided_traces=5,
    val_targets=1,
    val_repeats=1,
    choice_temperatures=(1.0, 0.5),
    ess=(None,),
    curve_guided=(1, 3),
    curve_unguided=(3, 10),
    estimates={"rounds": 10.0, "tune": 1.0, "curve": 1.0},
    reasons=("a fixed plan for the tests",),
)


def use_tiny_plan(monkeypatch):
    monkeypatch.setattr(learn_mod, "plan", lambda budget, costs: TINY)
    monkeypatch.setattr(learn_mod, "replan", lambda p, left, costs, trained: TINY)
    monkeypatch.setattr(learn_mod, "fill", lambda *args: None)  # no rounds added
    monkeypatch.setattr(learn_mod, "OWN_TRACES", 5)  # ground-truth traces on envelopes


@pytest.fixture()
def tiny_plan(monkeypatch):
    use_tiny_plan(monkeypatch)


def small(tmp_path: Path, budget: float = 600.0, grammar: str = CHAIN) -> LearnConfig:
    """A learn run on 3 bar targets, validated on 2 others (no datasets built)."""
    train = make_dataset(tmp_path / "train", 3)
    val = make_dataset(tmp_path / "val", 2)
    return LearnConfig(
        grammar=grammar,
        out=str(tmp_path / "out"),
        budget=budget,
        targets=[str(train)],
        validation={"bars": str(val)},
        workers=1,
        progress=False,
    )


def stages(out: Path) -> dict:
    return json.loads((out / "learn.json").read_text())["stages"]


def test_cli_learn_writes_a_guide_and_a_report(tmp_path, capsys, tiny_plan):
    data = make_dataset(tmp_path / "data", 3)
    out = tmp_path / "out"
    argv = ["learn", CHAIN, "-o", str(out), "--budget", "10m", "--targets", str(data)]
    assert main([*argv, "--workers", "1"]) == 0
    onnx.checker.check_model(onnx.load(str(out / "guide.onnx")))
    done = stages(out)
    assert list(done) == [
        *("diagnose", "targets", "reach", "measure", "plan", "round_00", "replan", "round_01"),
        *("tune", "curve"),
    ]
    assert done["round_01"]["result"]["teacher"] == "guided N=10 by round 0"
    assert done["round_01"]["result"]["traces"] == 10  # trained on both rounds' traces
    tuned = done["tune"]["result"]
    assert (out / "guide.onnx").read_bytes() == Path(tuned["guide"]).read_bytes()
    report = (out / "report.md").read_text()
    for part in ("## Rounds", "## Budget plan", "## Wall time per stage", "| round_01 |"):
        assert part in report
    assert "| 10 |  | " in report  # the curve: unguided alone at N = 10
    assert (out / "curve.png").is_file() and "![similarity vs N](curve.png)" in report
    assert (out / "chain.lsys").read_text() == Path(CHAIN).read_text()
    # validation sets were built: varied and shapes strokes of other seeds
    assert sorted(done["targets"]["result"]["validation"]) == ["shapes", "varied"]
    assert capsys.readouterr().out.rstrip().endswith(f"(report: {out / 'report.md'})")


@pytest.mark.slow
def test_cli_learn_fits_a_budget_of_seconds(tmp_path, capsys):
    """The real planner: a 30 s budget gives a guide (round 0 at least) and stops in time."""
    data = make_dataset(tmp_path / "data", 3)
    out = tmp_path / "out"
    argv = ["learn", CHAIN, "-o", str(out), "--budget", "30s", "--targets", str(data)]
    assert main([*argv, "--workers", "1"]) == 0
    onnx.checker.check_model(onnx.load(str(out / "guide.onnx")))
    state = json.loads((out / "learn.json").read_text())
    assert state["spent"] < 30 + 15  # the stop comes at the next trace, epoch or stage
    assert "round_00" in state["stages"]
    assert (out / "report.md").is_file()


def test_an_interrupted_run_resumes_without_redoing_finished_stages(
    tmp_path, monkeypatch, tiny_plan
):
    cfg = small(tmp_path)

    def interrupted(run, p):
        raise KeyboardInterrupt

    monkeypatch.setattr(learn_mod, "tune_stage", interrupted)
    with pytest.raises(KeyboardInterrupt):
        learn(cfg, log=lambda _m: None)
    out = Path(cfg.out)
    first = stages(out)
    assert "round_00" in first and "tune" not in first
    spent = json.loads((out / "learn.json").read_text())["spent"]
    assert spent > 0
    monkeypatch.undo()
    use_tiny_plan(monkeypatch)
    logs: list[str] = []
    res = learn(cfg, log=logs.append)
    assert not any(m.startswith("round_00: started") for m in logs)
    assert any(m.startswith("tune: started") for m in logs)
    again = stages(out)
    assert again["round_00"] == first["round_00"]  # the finished round is kept as it was
    assert res["state"]["spent"] >= spent
    onnx.checker.check_model(onnx.load(res["guide"]))


def test_the_budget_stop_keeps_the_best_finished_guide(tmp_path, monkeypatch, tiny_plan):
    cfg = small(tmp_path)

    def spends_the_budget(run, p):
        run.clock.before += run.clock.budget
        run.clock.check("tuning")

    monkeypatch.setattr(learn_mod, "tune_stage", spends_the_budget)
    res = learn(cfg, log=lambda _m: None)
    out = Path(cfg.out)
    assert res["stopped"] == "tuning"
    round_0 = stages(out)["round_00"]["result"]["guide"]
    assert (out / "guide.onnx").read_bytes() == Path(round_0).read_bytes()
    assert "The budget ran out during tuning" in (out / "report.md").read_text()


def test_a_budget_too_small_for_one_guide_is_one_line(tmp_path, capsys):
    data = make_dataset(tmp_path / "data", 3)
    out = tmp_path / "out"
    argv = ["learn", CHAIN, "-o", str(out), "--budget", "0.01s", "--targets", str(data)]
    assert main([*argv, "--workers", "1"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("ngpmc: error: the budget of 0 s was spent during ")
    assert "before a guide was trained; rerun with a larger --budget" in err
    assert len(err.strip().splitlines()) == 1
    assert not (out / "guide.onnx").exists()


def test_a_stop_during_traces_keeps_the_finished_jobs(tmp_path, monkeypatch, tiny_plan):
    cfg = small(tmp_path)
    calls: list[str] = []
    real = learn_mod.Clock.check

    def check(self, where):
        if "traces" in where:
            calls.append(where)
            if len(calls) == 4:
                raise BudgetSpent(where)
        real(self, where)

    monkeypatch.setattr(learn_mod.Clock, "check", check)
    with pytest.raises(LearnError, match="spent during round 0's traces before a guide"):
        learn(cfg, log=lambda _m: None)
    traces = Path(cfg.out) / "rounds" / "round_0" / "traces_0"
    manifest = json.loads((traces / "manifest.json").read_text())
    assert manifest["jobs_done"] == 4  # written although the round did not finish
    monkeypatch.undo()
    use_tiny_plan(monkeypatch)
    logs: list[str] = []
    learn(cfg, log=logs.append)
    assert "round_00" in stages(Path(cfg.out))


def test_an_exploding_grammar_is_refused_naming_the_rule(tmp_path):
    grammar = tmp_path / "explode.lsys"
    grammar.write_text(EXPLODING)
    with pytest.raises(LearnError, match=f"explode.lsys:{EXPLODING_LINE}: rule A branches"):
        learn(small(tmp_path, grammar=str(grammar)), log=lambda _m: None)


def test_a_grammar_without_a_viewport_gets_the_proposed_one(tmp_path):
    text = "\n".join(
        line for line in Path(CHAIN).read_text().splitlines() if not line.startswith("viewport:")
    )
    grammar = tmp_path / "chain.lsys"
    grammar.write_text(text + "\n")
    cfg = small(tmp_path)
    cfg.grammar = str(grammar)
    res = learn_mod.open_run(cfg, lambda _m: None)
    d = learn_mod.diagnose_stage(res)
    assert d["viewport_proposed"] is not None
    copy = Path(d["grammar"]).read_text()
    assert copy.startswith("viewport: ") and copy.endswith(text + "\n")


def test_another_configuration_in_the_same_folder_is_refused(tmp_path):
    cfg = small(tmp_path)
    learn_mod.open_run(cfg, lambda _m: None)
    cfg.seed = 1
    with pytest.raises(LearnError, match="holds a learn run of another configuration .*seed"):
        learn_mod.open_run(cfg, lambda _m: None)
    cfg.seed, cfg.out = 0, str(tmp_path / "tuned")
    cfg.tune_teachers = True  # a key only the folder's run has is named too
    learn_mod.open_run(cfg, lambda _m: None)
    cfg.tune_teachers = False
    with pytest.raises(LearnError, match="differs in tune_teachers\\)"):
        learn_mod.open_run(cfg, lambda _m: None)


def test_a_round_whose_traces_overrun_trains_on_what_it_has(tmp_path, monkeypatch, tiny_plan):
    """Traces slower than measured: the round stops recording at its share of the budget
    and still trains, validates and writes a guide (it is not lost at the budget's end)."""
    monkeypatch.setattr(learn_mod, "trace_allowance", lambda planned, left, reserve: 0.0)
    cfg = small(tmp_path)
    res = learn(cfg, log=lambda _m: None)
    done = stages(Path(cfg.out))
    assert 1 <= done["round_00"]["result"]["traces"] < TINY.traces
    assert any("stopped at its share of the budget" in n for n in res["state"]["notes"])
    onnx.checker.check_model(onnx.load(res["guide"]))


def test_a_training_longer_than_its_share_stops_early_and_the_run_still_tunes(
    tmp_path, monkeypatch, tiny_plan
):
    """A training slower than estimated stops after an epoch once the time it must leave
    (validation, tuning, the curve) is reached: the rounds keep a guide, the run tunes."""
    whole = learn_mod.train  # each training told to leave more time than there is
    monkeypatch.setattr(
        learn_mod, "train", lambda run, rc, r, dirs, keep: whole(run, rc, r, dirs, 1e9)
    )
    cfg = small(tmp_path)
    res = learn(cfg, log=lambda _m: None)
    done = stages(Path(cfg.out))
    for r in ("round_00", "round_01"):
        assert done[r]["result"]["train_stopped"] and done[r]["result"]["train_epochs"] == 1
    assert done["tune"]["result"] is not None
    assert "stopped for time" in (Path(cfg.out) / "report.md").read_text()
    onnx.checker.check_model(onnx.load(res["guide"]))


def test_a_training_stopped_for_time_does_not_lower_the_training_cost():
    def row(seconds, traces, stopped=False):
        return {"seconds": {"train": seconds}, "traces": traces, "train_stopped": stopped}

    whole = row(210.0, 1000)  # (210 - 10) / 1000 = 0.2 s a trace
    assert train_cost([whole]) == pytest.approx(0.2)
    assert train_cost([whole, row(60.0, 2000, stopped=True)]) == pytest.approx(0.2)
    assert train_cost([whole, row(1010.0, 2000, stopped=True)]) == pytest.approx(0.5)
    assert train_cost([whole, row(60.0, 2000)]) == pytest.approx(0.025)


def one_more_round(p, total, left, costs, done, trained, val, **_kw):
    """learn_plan.extend as a tiny fixed extension: one guided round of 5 traces."""
    return replace(
        p,
        total=total,
        budget=left,
        rounds=done + 1,
        guided_traces=5,
        reasons=(*p.reasons, f"budget {total:.0f} s: 1 guided round(s) added after round {done}"),
    )


def test_a_rerun_with_a_larger_budget_adds_rounds(tmp_path, monkeypatch, tiny_plan):
    """A finished run, rerun with a larger --budget: the finished rounds stay as they were,
    one more guided round is planned and run (taught by the best round, trained on every
    round's traces), tuning and the curve run again for the new guide, the report says
    what the rerun added; the same budget again adds nothing."""
    cfg = small(tmp_path)
    learn(cfg, log=lambda _m: None)
    out = Path(cfg.out)
    first = stages(out)
    calls = []

    def extend(p, total, left, costs, done, trained, val, **kw):
        calls.append((total, done, trained, kw))
        return one_more_round(p, total, left, costs, done, trained, val)

    monkeypatch.setattr(learn_mod, "extend", extend)
    cfg.budget = 1200.0
    logs: list[str] = []
    res = learn(cfg, log=logs.append)
    again = stages(out)
    assert calls == [(1200.0, 1, 10, {"fixed": False, "curve_done": True})]
    assert any(m.startswith("the budget grew from 10.0 min to 20.0 min") for m in logs)
    for name in ("round_00", "round_01", "tune", "curve"):
        assert again[name] == first[name]  # kept as they were
    assert list(again)[len(first) :] == ["extend_1", "round_02", "tune_1", "curve_1"]
    r2 = again["round_02"]["result"]
    assert r2["traces"] == 15 and r2["teacher"].startswith("guided N=10 by round ")
    assert again["tune_1"]["result"]["guide"].endswith("tuned_1.onnx")
    assert Path(first["tune"]["result"]["guide"]).is_file()  # not overwritten
    report = (out / "report.md").read_text()
    assert "## Reruns with a larger budget" in report
    assert "- `extend_1`: the budget grew from 10.0 min to 20.0 min after " in report
    assert "Added round(s) 2 (5 traces): best validation similarity " in report
    assert "| round_02 |" in report and "| extend_1 |" in report
    best = max(range(3), key=lambda r: (again[f"round_0{r}"]["result"]["validation"], -r))
    assert again["tune_1"]["result"]["round"] == best
    assert (out / "guide.onnx").read_bytes() == Path(res["guide"]).read_bytes()
    learn(cfg, log=logs.append)  # the same budget again: nothing new
    assert stages(out) == again and len(calls) == 1


def test_a_rerun_whose_extension_adds_no_round_runs_nothing_more(tmp_path, monkeypatch, tiny_plan):
    cfg = small(tmp_path)
    learn(cfg, log=lambda _m: None)
    out = Path(cfg.out)
    first = stages(out)
    monkeypatch.setattr(
        learn_mod,
        "extend",
        lambda p, total, left, costs, done, trained, val, **kw: replace(
            p, total=total, budget=left, rounds=done, reasons=(*p.reasons, "nothing fits")
        ),
    )
    cfg.budget = 700.0
    learn(cfg, log=lambda _m: None)
    again = stages(out)
    assert list(again) == [*first, "extend_1"]
    assert "- `extend_1`: the budget grew from 10.0 min to 11.7 min" in (
        (out / "report.md").read_text()
    )
    assert "Added no finished round." in (out / "report.md").read_text()


def test_a_rerun_that_can_now_tune_tunes_and_measures_the_curve_again(tmp_path, monkeypatch):
    """A first run too small to tune; the rerun's extension adds no round but a tune grid:
    tune_1 and curve_1 run and OUT/guide.onnx becomes the tuned best round."""
    untuned = replace(TINY, choice_temperatures=(), ess=())
    monkeypatch.setattr(learn_mod, "plan", lambda budget, costs: untuned)
    monkeypatch.setattr(learn_mod, "replan", lambda p, left, costs, trained: untuned)
    monkeypatch.setattr(learn_mod, "fill", lambda *args: None)
    cfg = small(tmp_path)
    learn(cfg, log=lambda _m: None)
    out = Path(cfg.out)
    assert stages(out)["tune"]["result"] is None
    monkeypatch.setattr(
        learn_mod,
        "extend",
        lambda p, total, left, costs, done, trained, val, **kw: replace(
            p, total=total, budget=left, rounds=done, choice_temperatures=(1.0, 0.5), ess=(None,)
        ),
    )
    cfg.budget = 900.0
    learn(cfg, log=lambda _m: None)
    done = stages(out)
    assert list(done)[-3:] == ["extend_1", "tune_1", "curve_1"]
    assert done["extend_1"]["result"]["renews"] is True
    tuned = done["tune_1"]["result"]["guide"]
    assert (out / "guide.onnx").read_bytes() == Path(tuned).read_bytes()
    report = (out / "report.md").read_text()
    assert "Added no finished round (tuning and the curve run again)." in report
    assert ", tuned (" in report


def _stage_run(tmp_path: Path, seed: int) -> learn_mod.Run:
    cfg = LearnConfig(grammar=CHAIN, out=str(tmp_path / "out"), budget=48.0, seed=seed)
    return learn_mod.Run(cfg, {}, learn_mod.Clock(48.0, 0.0), print)


def test_the_built_validation_targets_are_not_training_targets(tmp_path):
    dirs = learn_mod.targets_stage(_stage_run(tmp_path, 0))
    train = {p.read_bytes() for d in dirs["train"] for p in Path(d).glob("*.png")}
    val = [p.read_bytes() for d in dirs["validation"].values() for p in Path(d).glob("*.png")]
    assert train and val and not train & set(val)


def test_a_seed_that_would_train_on_the_validation_targets_is_refused(tmp_path):
    seed = learn_mod.VALIDATION["varied"][1] - 1  # varied is built with cfg.seed + 1
    with pytest.raises(LearnError, match="validation targets; choose another seed"):
        learn_mod.targets_stage(_stage_run(tmp_path, seed))


def test_cli_learn_circuit_trains_without_targets(tmp_path, capsys, tiny_plan):
    """--likelihood circuit: no targets built or read; traces under equation 2 from the
    blank canvas, validation and the curve scored by its argument."""
    out = tmp_path / "out"
    argv = ["learn", CHAIN, "-o", str(out), "--budget", "10m", "--likelihood", "circuit"]
    assert main([*argv, "--workers", "1"]) == 0
    onnx.checker.check_model(onnx.load(str(out / "guide.onnx")))
    done = stages(out)
    assert "tune" in done and "curve" in done
    assert done["targets"]["result"] == {"train": [""], "validation": {"circuit": ""}}
    assert not (out / "targets").exists()
    for r in ("round_00", "round_01"):
        for d in done[r]["result"]["traces_dirs"]:
            key = json.loads((Path(d) / "manifest.json").read_text())["key"]
            assert key["likelihood"] == "circuit" and key["targets"] == ["circuit"]
    assert 0 < done["round_01"]["result"]["validation"] <= 1  # a circuit score
    assert {row["dataset"] for row in done["curve"]["result"]} == {"validation"}
    assert "Likelihood: circuit (equation 2)" in (out / "report.md").read_text()
    # --targets has no meaning here: one line before any work
    assert main([*argv, "--targets", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "the circuit likelihood has no targets: drop --targets" in err


def test_time_left_after_the_planned_rounds_adds_a_round_with_a_stronger_teacher(
    tmp_path, monkeypatch, tiny_plan
):
    """The planned rounds done with time left: learn plans a round more (learn_plan.fill,
    recorded as fill_0_1) at its particles, runs it, and tries again (nothing more fits)."""
    calls = []

    def one_more(p, left, costs, trained, val, reserve):
        calls.append(trained)
        if len(calls) > 1:
            return None
        return replace(p, more=((4, 12),), reasons=(*p.reasons, "after round 1: one more"))

    monkeypatch.setattr(learn_mod, "fill", one_more)
    res = learn(small(tmp_path), log=lambda _m: None)
    st = stages(tmp_path / "out")
    assert "fill_0_1" in st and "round_02" in st and "fill_0_2" not in st
    assert st["round_02"]["result"]["teacher"].startswith("guided N=12 by round ")
    assert len(calls) == 2 and calls[1] > calls[0]  # asked again after round 2, more traces
    report = Path(res["report"]).read_text()
    assert "round 2: 4 traces with 12 particles" in report
    assert "- after round 1: one more" in report


@pytest.mark.parametrize("fit", [MIN_TRACES, MIN_TRACES - 1])
def test_a_round_too_long_for_the_time_left_runs_when_enough_of_its_traces_fit(
    tmp_path, monkeypatch, tiny_plan, fit
):
    """A planned round estimated over the time left before tuning runs anyway (its traces
    stop at their share) when MIN_TRACES of them fit; with fewer it is skipped."""
    monkeypatch.setattr(learn_mod, "_next_round_estimate", lambda run, p, r: 1e9)
    monkeypatch.setattr(learn_mod, "traces_that_fit", lambda *args: fit)
    lines: list[str] = []
    learn(small(tmp_path), log=lines.append)
    st = stages(tmp_path / "out")
    notes = json.loads((tmp_path / "out" / "learn.json").read_text()).get("notes", [])
    if fit >= MIN_TRACES:
        assert "round_01" in st
        assert any("about 5 of its 5 traces fit" in m for m in lines)
    else:
        assert "round_01" not in st
        assert sum(n.startswith("round 1 skipped") for n in notes) == 1  # said once


def test_a_grammar_that_cannot_reach_the_targets_warns_and_goes_on(tmp_path, tiny_plan):
    grammar = tmp_path / "speck.lsys"
    grammar.write_text(SPECK)
    logs: list[str] = []
    res = learn(small(tmp_path, grammar=str(grammar)), log=logs.append)
    warning = [m for m in logs if m.startswith("warning: speck.lsys: unguided SMC with ")]
    assert len(warning) == 1 and "too small or too little" in warning[0]
    assert Path(res["guide"]).is_file()  # a warning, not an error
    r = stages(tmp_path / "out")["reach"]["result"]
    assert r["low"] and r["similarity"] < 0.15
    report = Path(res["report"]).read_text()
    grammar_section = report.split("## Grammar")[1].split("## Rounds")[0]
    assert warning[0] in grammar_section


BUSH = str(Path(CHAIN).with_name("bush.lsys"))


def few_targets(monkeypatch) -> None:
    """Small target sets, so that building them takes a moment."""
    monkeypatch.setattr(learn_mod, "_train_count", lambda budget: 6)
    monkeypatch.setattr(learn_mod, "VAL_COUNT", 3)


def test_generic_targets_out_of_reach_switch_to_envelopes(tmp_path, monkeypatch, tiny_plan):
    """The bush (a bounded plant) cannot reach scribbles and varied strokes: without
    --targets, learn trains and validates on envelopes of its own samples, says so in one
    line and in the report, and a resumed run keeps them."""
    few_targets(monkeypatch)
    cfg = LearnConfig(grammar=BUSH, out=str(tmp_path / "out"), workers=1, progress=False)
    logs: list[str] = []
    res = learn(cfg, log=logs.append)
    lines = [m for m in logs if m.startswith("targets: unguided SMC with ")]
    assert len(lines) == 1 and "training and validating on envelopes instead" in lines[0]
    assert not [m for m in logs if m.startswith("warning:")]
    done = stages(tmp_path / "out")
    switch = done["envelopes"]["result"]
    assert switch["switched"] and done["reach"]["result"]["low"]
    assert switch["reach"]["similarity"] > max(0.15, done["reach"]["result"]["similarity"])
    assert list(switch["targets"]["validation"]) == ["envelopes"]
    # every round: ground-truth traces (forward samples into their own envelopes), each
    # round its own seed, training on all of them; no SMC traces
    rounds = [done[k]["result"] for k in ("round_00", "round_01")]
    assert [x["teacher"] for x in rounds] == [learn_mod.OWN_TEACHER] * 2
    assert [x["traces"] for x in rounds] == [5, 10]
    # trained with the far look-ahead and patience 10 (learn_plan.ENVELOPE_TRAINING)
    # round 1's training starts from round 0's weights, with a shorter patience
    assert [(x["features"], x["patience"], x["warm_start"]) for x in rounds] == [
        ("all+context+far", 10, False),
        ("all+context+far", 4, True),
    ]
    meta = {p.key: p.value for p in onnx.load(res["guide"]).metadata_props}
    assert json.loads(meta["features"])["feature_set"] == "all+context+far"
    keys = []
    for r in (0, 1):
        m = json.loads((tmp_path / f"out/rounds/round_{r}/own_samples/manifest.json").read_text())
        assert m["key"]["own_samples"] and m["key"]["targets"] == [] and m["kept"] == 5
        keys.append(m["key"]["seed"])
    assert keys[0] != keys[1]
    assert not (tmp_path / "out/rounds/round_1/traces_0").exists()
    for runs in ("rounds/validation/heldout.csv", "work/curve/heldout.csv"):
        rows = (tmp_path / "out" / runs).read_text().splitlines()[1:]
        assert rows and {r.split(",")[0] for r in rows} == {"envelopes"}
    report = Path(res["report"]).read_text()
    assert lines[0] in report and "validation envelopes (`val_envelopes`)" in report
    assert "recorded its own samples' ground-truth traces in place of these" in report
    assert "features all+context+far, hidden units 2.0 per input, 4 mixture" in report
    assert "early stopping (patience 10, 4 epochs), rounds 1 warm-started" in report
    logs.clear()
    learn(cfg, log=logs.append)  # resumed: every stage done, the same targets
    assert stages(tmp_path / "out") == done
    assert any(m.startswith("targets: unguided SMC with ") for m in logs)


def test_a_run_measured_before_the_switch_existed_keeps_its_targets(tmp_path):
    """A learn.json whose reach was low but which went on measuring (made before envelopes
    existed) is not switched halfway: the warning, and the same targets."""
    run = _stage_run(tmp_path, 0)
    run.state = {"stages": {"measure": {"seconds": 1.0, "result": 0.01}}}
    logs: list[str] = []
    run.log = logs.append
    t = {"train": ["a"], "validation": {"varied": "b"}}
    reach = {"warning": "warning: bush.lsys: unguided SMC ..."}
    assert learn_mod.switch_targets(run, {"grammar": BUSH}, t, reach) is t
    assert logs == [reach["warning"]] and "envelopes" not in run.state["stages"]


def test_cli_learn_targets_envelopes_asks_for_them(tmp_path, capsys, monkeypatch, tiny_plan):
    few_targets(monkeypatch)
    out = tmp_path / "out"
    argv = ["learn", BUSH, "-o", str(out), "--budget", "10m", "--targets", "envelopes"]
    assert main([*argv, "--workers", "1"]) == 0
    state = json.loads((out / "learn.json").read_text())
    assert state["key"]["targets"] == ["envelopes"]
    t = state["stages"]["targets"]["result"]
    assert t["kind"] == "envelopes" and t["train"] == [str(out / "targets" / "envelopes")]
    assert t["validation"] == {"envelopes": str(out / "targets" / "val_envelopes")}
    assert "envelopes" not in state["stages"] and not state["stages"]["reach"]["result"]["low"]
    assert main(["learn", BUSH, "-o", str(tmp_path / "o2"), "--targets", f"envelopes,{out}"])
    assert "--targets envelopes takes no other folders" in capsys.readouterr().err


def test_a_seed_that_would_train_on_the_validation_envelopes_is_refused(tmp_path):
    run = _stage_run(tmp_path, learn_mod.ENVELOPE_VALIDATION["envelopes"][1])
    run.cfg.targets = [learn_mod.ENVELOPES]
    with pytest.raises(LearnError, match="validation envelopes; choose another seed"):
        learn_mod.targets_stage(run, BUSH)


SHRUB3D = """\
# a small 3D shrub: each bud grows on and forks, or ends in a ball of foliage
derivation length: 4
viewport: -12 12 0 24 -12 12
Axiom: !(1.2) A
A --> F(4) /(gauss(0, 60)) [&(gauss(35, 10)) A] A : 0.5
A --> F(3) @O(uniform(1.5, 4)) : 0.5
"""


def test_cli_learn_a_3d_grammar_learns_on_3d_targets(tmp_path, capsys, monkeypatch, tiny_plan):
    """A 3D grammar learns as a 2D one does, on 3D target sets built for it (blobs3d and
    extruded, validation of other seeds), with the 3D features (no context group); the
    reach line speaks of the box, and the guide grows into a 3D target."""
    from ngpm_runtime.inference.guide import Guide

    from ngpm_compiler.language.compile import load_grammar

    few_targets(monkeypatch)
    grammar = tmp_path / "shrub3d.lsys"
    grammar.write_text(SHRUB3D)
    out = tmp_path / "out"
    assert main(["learn", str(grammar), "-o", str(out), "--budget", "10m", "--workers", "1"]) == 0
    onnx.checker.check_model(onnx.load(str(out / "guide.onnx")))
    done = stages(out)
    assert "round_01" in done and "tune" in done and "curve" in done
    assert done["diagnose"]["result"]["dim"] == 3
    t = done["targets"]["result"]
    assert [Path(d).name for d in t["train"]] == ["blobs3d", "extruded"]
    assert sorted(t["validation"]) == ["blobs3d", "extruded"]
    assert "envelopes" not in done and done["reach"]["result"]["dim"] == 3
    key = json.loads((out / "rounds/round_0/traces_0/manifest.json").read_text())["key"]
    assert key["targets"][0].startswith("blobs3d_") and not key["mirror"]
    program = load_grammar(str(grammar))
    assert Guide.load(out / "guide.onnx", program).feature_set == "all"
    report = (out / "report.md").read_text()
    assert "of the box" in report and "- features all," in report
    target = next((out / "targets" / "val_blobs3d").glob("*.npz"))
    tree = tmp_path / "tree.glb"
    args = ["grow", str(target), "--grammar", str(grammar), "--guide", str(out / "guide.onnx")]
    assert main([*args, "-N", "3", "-o", str(tree)]) == 0
    assert tree.read_bytes()[:4] == b"glTF"


@pytest.mark.parametrize(
    ("text", "extra", "message"),
    [
        (SHRUB3D, ["--likelihood", "circuit"], "a 3D grammar learns with the shape likelihood"),
        (SHRUB3D, ["--targets", "envelopes"], "--targets envelopes is for 2D grammars"),
        (
            SHRUB3D.replace("viewport: -12 12 0 24 -12 12\n", "dimensions: 3\n"),
            [],
            "a 3D grammar needs its box to grow into targets",
        ),
    ],
)
def test_a_3d_grammar_it_cannot_learn_for_is_one_line(tmp_path, capsys, text, extra, message):
    grammar = tmp_path / "shrub3d.lsys"
    grammar.write_text(text)
    assert main(["learn", str(grammar), "-o", str(tmp_path / "out"), *extra]) == 1
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_tune_teachers_records_the_guided_round_with_the_tuned_teacher(tmp_path, capsys, tiny_plan):
    """--tune-teachers: the guided round's teacher is round 0's guide tuned on the
    validation targets (its settings in the report's teacher column), its traces recorded
    with that file; the option is part of the run's key (a run without it is refused)."""
    from ngpm_runtime.inference.guide import Guide

    from ngpm_compiler.language.compile import load_grammar

    data = make_dataset(tmp_path / "data", 3)
    out = tmp_path / "out"
    argv = ["learn", CHAIN, "-o", str(out), "--budget", "10m", "--targets", str(data)]
    assert main([*argv, "--workers", "1", "--tune-teachers"]) == 0
    done = stages(out)
    teacher = out / "rounds" / "round_0" / "teacher.onnx"
    settings = Guide.load(teacher, load_grammar(CHAIN)).settings
    assert settings.choice_temperature in (1.0, 0.5)
    want = f"guided N=10 by round 0, tuned {settings.label()}"
    assert done["round_01"]["result"]["teacher"] == want
    manifest = json.loads(
        next((out / "rounds" / "round_1").glob("traces_*/manifest.json")).read_text()
    )
    assert manifest["config"]["guide"] == str(teacher)
    assert want in (out / "report.md").read_text()
    capsys.readouterr()
    assert main([*argv, "--workers", "1"]) != 0  # another configuration: refused
    assert "tune_teachers" in capsys.readouterr().err


def test_a_cold_kernel_cache_is_filled_before_the_timed_stages(tmp_path, monkeypatch, tiny_plan):
    """The reach and measure stages time SMC runs: with the kernels' disk cache cold they
    would time numba's compiles, so learn compiles first (once: not when resumed)."""
    import ngpm_runtime.warmup as warmup

    calls: list[str] = []
    real_measure = learn_mod.measure_stage

    def measure(*args, **kwargs):
        calls.append("measure")
        return real_measure(*args, **kwargs)

    monkeypatch.setattr(warmup, "cache_is_cold", lambda: True)
    monkeypatch.setattr(warmup, "warm_up", lambda: calls.append("warm_up") or 1.0)
    monkeypatch.setattr(learn_mod, "measure_stage", measure)
    lines: list[str] = []
    cfg = small(tmp_path)
    learn(cfg, log=lines.append)
    assert calls[:2] == ["warm_up", "measure"] and calls.count("warm_up") == 1
    assert any("kernels: compiled in 1 s" in line for line in lines)
    learn(cfg, log=lines.append)  # resumed: measured already, nothing compiled
    assert calls.count("warm_up") == 1
