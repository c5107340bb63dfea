"""The budget planner of `ngpmc learn` (experiments/learn_plan.py): pure functions."""

from __future__ import annotations

import pytest

from ngpm_compiler.experiments.learn_plan import (
    CURVE_GUIDED,
    GUIDED_PARTICLES,
    MIN_PARTICLES,
    MIN_TRACES,
    TRAIN_FIXED,
    TUNE_CHOICES,
    UNGUIDED_PARTICLES,
    Costs,
    parse_budget,
    plan,
    round_seconds,
)

# vines on the 2-core test machine: about 5 ms per unguided particle, guided 4x
VINES = Costs(unguided=0.005, guided=0.02, train=0.2, workers=2, sets=2)


def planned_seconds(p, costs: Costs) -> float:
    return sum(p.estimates.values())


def test_a_large_budget_gets_the_recipe():
    p = plan(2 * 3600, VINES)
    assert (p.unguided_particles, p.guided_particles) == (UNGUIDED_PARTICLES, GUIDED_PARTICLES)
    assert p.rounds >= 2 and p.traces >= MIN_TRACES
    assert (p.val_targets, p.val_repeats) == (12, 2)
    temps, ess = TUNE_CHOICES[0]
    assert (p.choice_temperatures, p.ess) == (temps, ess)
    assert p.curve_guided == CURVE_GUIDED
    assert planned_seconds(p, VINES) <= 2 * 3600
    assert any("guided rounds" in r for r in p.reasons)


@pytest.mark.parametrize("minutes", [5, 15, 45, 120, 480])
def test_the_plan_fits_the_budget(minutes):
    p = plan(minutes * 60, VINES)
    assert planned_seconds(p, VINES) <= minutes * 60
    assert p.traces >= 2 and MIN_PARTICLES <= p.guided_particles <= p.unguided_particles


def test_more_budget_never_plans_less_work():
    work = [
        (p.rounds + 1) * p.traces * p.unguided_particles
        for p in (plan(m * 60, VINES) for m in (5, 15, 45, 120))
    ]
    assert work == sorted(work)


def test_a_tiny_budget_shrinks_particles_and_drops_tuning():
    p = plan(20, VINES)
    assert p.rounds == 0
    assert p.unguided_particles < UNGUIDED_PARTICLES
    assert p.choice_temperatures == ()
    assert len(p.curve_guided) == 2 and len(p.curve_unguided) == 2
    assert (p.val_targets, p.val_repeats) == (1, 1)
    assert "no guided round" in p.reasons[1]


def test_dearer_guided_runs_plan_fewer_rounds():
    cheap = plan(45 * 60, VINES)
    dear = plan(45 * 60, Costs(unguided=0.005, guided=0.08, train=0.2, workers=2))
    assert dear.rounds < cheap.rounds or dear.traces < cheap.traces


def test_round_seconds_adds_traces_training_and_validation():
    c = Costs(unguided=0.01, guided=0.03, train=0.5, workers=2)
    # 100 traces of 200 guided particles on 2 workers, training on 300 traces, validation 7 s
    assert round_seconds(c, 100, 200, True, 300, 7.0) == pytest.approx(
        100 * 200 * 0.03 / 2 + TRAIN_FIXED + 150 + 7
    )
    assert c.run(10, False) == pytest.approx(0.1)
    assert Costs(unguided=0.01).run(10, True) == pytest.approx(0.4)  # guided: 4x, unmeasured


@pytest.mark.parametrize(
    "text, seconds",
    [("45m", 2700), ("2h", 7200), ("90s", 90), ("1h30m", 5400), ("120", 120), ("1.5h", 5400)],
)
def test_parse_budget(text, seconds):
    assert parse_budget(text) == seconds


@pytest.mark.parametrize("text", ["", "m", "5x", "-3m", "0s", "nan", "10m5", "inf"])
def test_parse_budget_refuses(text):
    with pytest.raises(ValueError):
        parse_budget(text)
