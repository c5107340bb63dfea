"""The budget planner of `ngpmc learn` (experiments/learn_plan.py): pure functions."""

from __future__ import annotations

from dataclasses import replace

import pytest

from ngpm_compiler.experiments.learn_plan import (
    CURVE_GUIDED,
    GUIDED_FACTOR,
    GUIDED_PARTICLES,
    MAX_ROUNDS,
    MAX_STRONG,
    MAX_STRONG_TRACES,
    MAX_TRACES,
    MIN_PARTICLES,
    MIN_TRACES,
    STRONG_PARTICLES,
    TRACE_GRACE,
    TRACE_SLACK,
    TRAIN_FIXED,
    TRAIN_SECONDS,
    TUNE_CHOICES,
    UNGUIDED_PARTICLES,
    Costs,
    extend,
    fill,
    parse_budget,
    plan,
    replan,
    reserve_seconds,
    round_seconds,
    strong_rounds,
    trace_allowance,
    traces_that_fit,
    train_per_trace,
)

# measured on the 2-core test machine (vines, ivy): unguided trace jobs about 1 ms per
# particle, guided 22 ms, a guided validation run at N = 10 0.7 s, training 0.05 s a trace
VINES = Costs(unguided=0.001, guided=0.022, val_run=0.7, train=0.05, workers=2, sets=2)


def planned_seconds(p, costs: Costs) -> float:
    return sum(p.estimates.values())


def test_a_large_budget_gets_the_recipe():
    p = plan(2 * 3600, VINES)
    assert (p.unguided_particles, p.guided_particles) == (UNGUIDED_PARTICLES, GUIDED_PARTICLES)
    assert p.rounds >= 2 and p.traces >= MIN_TRACES
    assert (p.val_targets, p.val_repeats) == (12, 8)
    # the widest tune grid where it fits its share, else the next
    assert (p.choice_temperatures, p.ess) == TUNE_CHOICES[2]
    q = plan(3 * 3600, VINES)
    assert (q.choice_temperatures, q.ess) == TUNE_CHOICES[1]
    q = plan(5 * 3600, VINES)
    assert (q.choice_temperatures, q.ess) == TUNE_CHOICES[0]
    assert p.curve_guided == CURVE_GUIDED
    assert planned_seconds(p, VINES) <= 2 * 3600
    assert "guided round(s) of" in p.reasons[1]


@pytest.mark.parametrize("minutes", [5, 15, 45, 120, 480])
def test_the_plan_fits_the_budget(minutes):
    p = plan(minutes * 60, VINES)
    assert planned_seconds(p, VINES) <= minutes * 60
    assert p.traces >= 2 and MIN_PARTICLES <= p.guided_particles <= p.unguided_particles


@pytest.mark.parametrize("minutes", [2, 15, 45, 120])
def test_the_plan_uses_most_of_the_budget(minutes):
    assert sum(plan(minutes * 60, VINES).estimates.values()) >= 0.8 * minutes * 60


def test_more_budget_never_plans_fewer_rounds_or_round_0_traces():
    plans = [plan(m * 60, VINES) for m in (1, 5, 15, 45, 120)]
    assert [p.rounds for p in plans] == sorted(p.rounds for p in plans)
    big = [p for p in plans if p.unguided_particles == UNGUIDED_PARTICLES]
    assert len(big) == len(plans)


def test_a_tiny_budget_shrinks_particles_and_drops_tuning():
    p = plan(15, VINES)
    assert p.rounds == 0
    assert p.unguided_particles < UNGUIDED_PARTICLES
    assert p.choice_temperatures == ()
    assert p.curve_guided == (1, 10) and len(p.curve_unguided) == 2  # guided keeps N = 10
    assert (p.val_targets, p.val_repeats) == (1, 1)
    assert "no guided round" in p.reasons[1]


def test_replan_sizes_the_guided_rounds_to_measured_costs():
    p = plan(45 * 60, Costs(unguided=0.001, workers=2))
    left = 30 * 60
    cheap = replan(p, left, VINES, p.traces)
    dear = replan(p, left, replace(VINES, guided=0.1), p.traces)
    assert cheap.traces == dear.traces == p.traces  # round 0 is done
    assert 0 < dear.rounds * dear.guided_traces * dear.guided_particles
    assert dear.rounds * dear.guided_traces * dear.guided_particles < (
        cheap.rounds * cheap.guided_traces * cheap.guided_particles
    )
    assert sum(cheap.estimates.values()) <= left
    assert cheap.reasons[-1].startswith("after round 0: ")
    none = replan(p, 60, VINES, p.traces)
    assert none.rounds == 0 and "no guided round" in none.reasons[-1]


def test_dearer_guided_runs_plan_fewer_rounds():
    cheap = plan(45 * 60, VINES)
    dear = plan(45 * 60, replace(VINES, guided=0.08))
    assert dear.rounds < cheap.rounds or dear.traces < cheap.traces


def test_round_seconds_adds_traces_training_and_validation():
    c = Costs(unguided=0.01, guided=0.03, train=0.5, workers=2)
    # 100 traces of 200 guided particles on 2 workers, training on 300 traces, validation 7 s
    assert round_seconds(c, 100, 200, True, 300, 7.0) == pytest.approx(
        100 * 200 * 0.03 / 2 + TRAIN_FIXED + 150 + 7
    )
    assert c.trace(10, False) == pytest.approx(0.1)
    assert Costs(unguided=0.01).trace(10, True) == pytest.approx(10 * 0.01 * GUIDED_FACTOR)
    # evaluation runs: a few particles cost as VAL_N (per-step overhead), guided from val_run
    assert replace(c, val_run=0.7).run(1, True) == replace(c, val_run=0.7).run(10, True) == 0.7
    assert replace(c, val_run=0.7).run(30, True) == pytest.approx(2.1)


@pytest.mark.parametrize(
    "text, seconds",
    [("45m", 2700), ("2h", 7200), ("90s", 90), ("1h30m", 5400), ("120", 120), ("1.5h", 5400)],
)
def test_parse_budget(text, seconds):
    assert parse_budget(text) == seconds


@pytest.mark.parametrize("text", ["", "m", "5x", "-3m", "0s", "nan", "10m5", "inf", "8d", "200h"])
def test_parse_budget_refuses(text):
    with pytest.raises(ValueError):
        parse_budget(text)


def test_trace_allowance_keeps_the_reserve():
    assert trace_allowance(100.0, 1000.0, 200.0) == pytest.approx(100.0 * TRACE_SLACK + TRACE_GRACE)
    assert trace_allowance(100.0, 250.0, 200.0) == pytest.approx(50.0)  # the reserve first
    assert trace_allowance(100.0, 150.0, 200.0) == 0.0


def finished(minutes: float):
    """The plan a run of `minutes` followed to its end (planned, then replanned)."""
    p = plan(minutes * 60, VINES)
    return replace(replan(p, 0.7 * minutes * 60, VINES, p.traces), total=minutes * 60)


def test_extend_adds_guided_rounds_after_the_finished_ones():
    p = finished(10)
    done = p.rounds
    q = extend(p, 45 * 60, 35 * 60, VINES, done, 900, 8.0)
    assert q.rounds > done and q.total == 45 * 60 and q.budget == 35 * 60
    assert q.guided_traces >= MIN_TRACES and q.guided_particles == GUIDED_PARTICLES
    assert sum(q.estimates.values()) <= 35 * 60
    # what the rounds and guides are compared on stays: validation, the curve
    assert (q.val_targets, q.val_repeats) == (p.val_targets, p.val_repeats)
    assert (q.curve_guided, q.curve_unguided) == (p.curve_guided, p.curve_unguided)
    assert q.traces == p.traces and q.unguided_particles == p.unguided_particles
    assert q.reasons[:-1] == p.reasons and "added after round" in q.reasons[-1]


def test_extend_adds_more_rounds_or_traces_with_more_time():
    p = finished(10)
    added = [extend(p, 600 + left, left, VINES, p.rounds, 900, 8.0) for left in (600, 1800, 7200)]
    work = [(q.rounds - p.rounds) * q.guided_traces * q.guided_particles for q in added]
    assert 0 < work[0] < work[1] < work[2]


def test_extend_with_too_little_time_adds_nothing():
    p = finished(45)
    q = extend(p, 46 * 60, 60, VINES, 2, 1500, 8.0)
    assert q.rounds == 2 and q.estimates["rounds"] == 0.0
    assert "no guided round added" in q.reasons[-1]


def test_extend_keeps_the_particles_of_a_cut_round():
    p = replace(finished(10), guided_particles=50)
    free = extend(p, 45 * 60, 35 * 60, VINES, 1, 900, 8.0)
    cut = extend(p, 45 * 60, 35 * 60, VINES, 1, 900, 8.0, fixed=True)
    assert free.guided_particles == GUIDED_PARTICLES and cut.guided_particles == 50


def test_extend_tunes_a_plan_that_had_no_grid():
    p = plan(15, VINES)
    assert p.choice_temperatures == ()
    q = extend(p, 45 * 60, 44 * 60, VINES, 0, p.traces, 8.0)
    assert q.choice_temperatures and q.estimates["tune"] > 0
    kept = extend(finished(45), 2 * 3600, 80 * 60, VINES, 2, 1500, 8.0)
    assert (kept.choice_temperatures, kept.ess) == TUNE_CHOICES[1]


def test_extend_counts_only_the_guided_curve_runs_when_the_curve_was_cached():
    p = finished(45)
    full = extend(p, 2 * 3600, 80 * 60, VINES, 2, 1500, 8.0)
    cached = extend(p, 2 * 3600, 80 * 60, VINES, 2, 1500, 8.0, curve_done=True)
    assert cached.estimates["curve"] < full.estimates["curve"]


def test_train_per_trace_leaves_out_the_fixed_part():
    assert train_per_trace(10 + 0.05 * 1000, 1000) == pytest.approx(0.05)
    assert train_per_trace(8.0, 1) == TRAIN_SECONDS  # one trace: all of it is fixed cost
    assert train_per_trace(5.0, 100) == pytest.approx(TRAIN_SECONDS / 20)


def test_a_small_first_run_is_extended_by_a_round_that_doubles_its_traces():
    """17 traces trained on: rounds of fewer than MIN_TRACES (but at least 17) are added;
    after 500 traces the same time adds none."""
    p = plan(60, VINES)
    assert p.rounds == 0 and p.traces < MIN_TRACES
    q = extend(p, 150, 90, VINES, 0, 17, 3.0)
    assert q.rounds == 1 and 17 <= q.guided_traces < MIN_TRACES
    assert extend(p, 150, 90, VINES, 0, 500, 3.0).rounds == 0


# measured by `ngpmc learn --budget 45m` (docs/results/learn_grammars.md, report.md's plan):
# seconds per particle of unguided and guided trace jobs, of a guided run at N = 10, of
# training per trace
PROFILES = {
    "lily": Costs(unguided=0.00216, guided=0.00144, val_run=0.13, train=0.01, workers=2),
    "bush": Costs(unguided=0.00111, guided=0.00145, val_run=0.12, train=0.01, workers=2),
    "ivy": Costs(unguided=0.00387, guided=0.00092, val_run=0.52, train=0.01, workers=2),
    "old vines": VINES,
    "unmeasured": Costs(unguided=0.002, workers=2),
    "one worker": Costs(unguided=0.004, guided=0.01, val_run=0.3, train=0.03, workers=1),
}


@pytest.mark.parametrize("name", sorted(PROFILES))
@pytest.mark.parametrize("minutes", [6, 15, 45, 120, 480])
def test_the_plan_fills_the_budget_without_exceeding_it(name, minutes):
    """The estimate of every stage together: from 90% to 100% of the budget, before and
    after round 0 (replan, at the measured costs)."""
    costs, budget = PROFILES[name], minutes * 60.0
    p = plan(budget, costs)
    assert 0.9 * budget <= planned_seconds(p, costs) <= budget
    left = 0.8 * budget
    q = replan(p, left, costs, p.traces)
    assert 0.9 * left <= planned_seconds(q, costs) <= left


def test_capped_rounds_leave_their_time_to_a_stronger_teacher():
    """lily at 45 min: four guided rounds reach MAX_TRACES each (the old plan stopped there,
    using 28.5 of 45 min); the rest goes to rounds with STRONG_PARTICLES particles."""
    costs = PROFILES["lily"]
    q = replan(plan(45 * 60, costs), 40 * 60, costs, 800)
    assert (q.rounds, q.guided_traces) == (MAX_ROUNDS, MAX_TRACES)
    assert q.more and all(pg == STRONG_PARTICLES for _, pg in q.more)
    assert q.last_round == MAX_ROUNDS + len(q.more)
    assert q.round_settings(1) == (MAX_TRACES, GUIDED_PARTICLES)
    assert q.round_settings(q.last_round) == q.more[-1]
    assert "stronger teacher" in q.reasons[-1]
    assert q.estimates["more rounds"] > 0


def test_a_small_budget_plans_no_strong_round():
    p = plan(15 * 60, PROFILES["lily"])
    assert p.more == () and p.guided_traces < MAX_TRACES


def test_strong_rounds_prefer_the_most_traces_then_more_particles():
    costs = PROFILES["lily"]
    one = strong_rounds(costs, 600, 10.0, 8000)
    assert one is not None and one[0] == 1 and one[2] == STRONG_PARTICLES
    rounds, n, pg, secs = strong_rounds(costs, 6 * 3600, 10.0, 8000)
    assert (rounds, n) == (MAX_STRONG, MAX_STRONG_TRACES) and pg > STRONG_PARTICLES
    assert 0.95 * 6 * 3600 <= secs <= 6 * 3600
    assert strong_rounds(costs, 30, 10.0, 8000) is None


def test_fill_adds_the_strong_rounds_that_fit_after_the_last_round():
    costs = PROFILES["lily"]
    p = replan(plan(45 * 60, costs), 40 * 60, costs, 800)
    q = fill(p, 12 * 60, costs, 12000, 10.0, 100.0)
    assert q is not None and q.more[: len(p.more)] == p.more and len(q.more) > len(p.more)
    assert q.estimates["more rounds"] <= 12 * 60 - 100
    assert q.reasons[-1].startswith(f"after round {p.last_round}: ")
    assert fill(p, 60, costs, 12000, 10.0, 100.0) is None


def test_reserve_seconds_times_tuning_and_the_curve_at_the_measured_costs():
    p = replan(plan(45 * 60, VINES), 40 * 60, VINES, 800)
    grid = len(p.choice_temperatures) * len(p.ess)
    assert grid > 0
    full = reserve_seconds(p, VINES, 6.0)
    assert reserve_seconds(p, VINES, 12.0) == pytest.approx(full + grid * 6.0)
    cached = reserve_seconds(p, VINES, 6.0, curve_done=True)
    assert 0 < cached < full  # the unguided curve runs are not counted again
    assert reserve_seconds(replace(p, choice_temperatures=(), ess=()), VINES, 6.0) < full


@pytest.mark.parametrize("room", [300.0, 900.0, 2400.0])
def test_traces_that_fit_fill_the_room_and_no_more(room):
    trained, val = 3000, 8.0
    n = traces_that_fit(VINES, GUIDED_PARTICLES, trained, val, room)
    assert n > 0
    assert round_seconds(VINES, n, GUIDED_PARTICLES, True, trained + n, val) <= room
    assert round_seconds(VINES, n + 1, GUIDED_PARTICLES, True, trained + n + 1, val) > room


def test_no_traces_fit_a_room_smaller_than_training_and_validation():
    assert traces_that_fit(VINES, GUIDED_PARTICLES, 3000, 8.0, TRAIN_FIXED) == 0
