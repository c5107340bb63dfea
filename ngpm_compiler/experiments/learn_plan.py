"""The budget plan of `ngpmc learn`: from the time budget and measured costs, how many
traces per round, how many particles, how many expert-iteration rounds, how many validation
targets, which tuning grid and which N values for the report's curve. Pure functions, no
clock and no files: `learn.py` measures, these decide.

Costs are seconds per SMC particle on one worker (a run of N particles costs about N times
that), so every stage's estimate is a sum of runs divided by the workers. The shares follow
the project's recipe (scripts/train_vines_guide.sh): 600 unguided particles for round 0,
200 guided particles in the later rounds, 12 validation targets per set run twice, the
tune grid of `ngpmc tune`; a small budget shrinks them in that order of cheapness.

When the guided rounds reach their caps (MAX_ROUNDS rounds of MAX_TRACES traces) with time
left, rounds with a stronger teacher fill it (`strong_rounds`: STRONG_PARTICLES guided
particles, as the recipe's fifth and sixth rounds; more particles when even MAX_STRONG rounds
of MAX_STRONG_TRACES leave time): the plan's estimate fills the budget. `learn.py` adds such
rounds again after the planned ones while the measured costs leave room (`Plan.more`).

A rerun with a larger budget extends the finished plan (`extend`): the finished rounds
stay, and the guided rounds that fit the time left after them are added, sized from the
costs the rounds measured; validation and the curve keep their settings, so the new rounds
and the new guide compare with the old.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

FEATURES = {2: "all+context", 3: "all"}  # the guides' feature set (3D rows have no context)
# on envelope targets (ground-truth traces) the far look-ahead too, and training that waits
# longer for a better epoch: a grammar learn trains on envelopes draws a plant top-down, its
# first choices made before anything is drawn; patience 4 stopped stochastic_plant's at
# epoch 15 (validation NLL 89.9 per trace), 10 at epoch 74 (86.6) (experiments/notes/
# far_lookahead.md: held out 0.191 -> 0.225 at N = 10 with both, bush unchanged). And
# networks 4 times as wide (hidden units twice the inputs, not half): 8000 such traces hold
# some 800000 rows a site, which the default width underfits (stochastic_plant: validation
# NLL 86.9 -> 85.8, 48 envelopes at N = 10 0.222 -> 0.246; notes/envelope_training.md).
# Data counts most (8000 -> 24000 traces: 85.3 -> 83.0, 0.241 -> 0.283 on 24 envelopes), so
# each round after the first starts from the round before's weights, which is within 0.8 of
# its best after one epoch, and stops after 4 epochs without a better one: rounds cost
# about their traces' epochs, not a whole new training, and more of them fit
ENVELOPE_TRAINING: dict[str, Any] = {
    "feature_set": "all+context+far",
    "epochs": 100,
    "patience": 10,
    "hidden_per_input": 2.0,
    "warm_start": True,
    "warm_patience": 4,
}
UNGUIDED_PARTICLES = 600  # round 0's teacher (the paper's)
GUIDED_PARTICLES = 200  # the guided rounds' teacher (expert iteration in the recipe)
# the teacher column of a round that recorded ground-truth traces (learn on envelopes)
OWN_TEACHER = "own samples (each into its envelope)"
MIN_PARTICLES = 20
MAX_ROUNDS = 4  # guided rounds after round 0
STRONG_PARTICLES = 600  # the stronger teacher of the recipe's rounds 5 and 6
MAX_STRONG = 4  # rounds with a stronger teacher after the guided ones
MAX_STRONG_TRACES = 3000  # per strong round (the recipe's round 6)
MAX_PARTICLES = 5000  # a strong teacher's particles at most
MIN_TRACES = 150  # a round with fewer traces is not worth its validation: fewer rounds
MAX_TRACES = 2000  # per round
FEW_TRACES = 20  # below this, round 0 runs fewer particles to get more traces
ROUND0_SHARE = 0.3  # of the time for traces, when guided rounds fit too
VAL_N = 10  # validation particles (the guides' working N)
STAGE_SECONDS = 2.0  # what starting a stage's worker processes costs
TRACE_SLACK = 1.5  # a round's traces may take this times their estimate (plus
TRACE_GRACE = 30.0  # these seconds: starting the workers), then the round trains
TRAIN_FIXED = 10.0  # a training's seconds beside its traces (start, checkpoints, export)
# until measured (learn at 45m on the 2-core machine, docs/results/learn_grammars.md:
# guided trace jobs 0.24x (ivy) to 1.3x (bush) the unguided seconds per particle; a guided
# run at N = 10 costs 9 to 56 times its particles' share of a trace job)
GUIDED_FACTOR = 1.0  # guided SMC's seconds per particle over unguided (features, networks)
SMALL_N = 3.0  # an unguided run of a few particles over its per-particle share
GUIDED_SMALL_N = 10.0  # the same for a guided run (per-step networks)
TRAIN_SECONDS = 0.2  # training seconds per trace (all epochs), until measured
MAX_BUDGET = 7 * 24 * 3600.0  # seconds: `--budget` at most a week
# (targets per validation set, runs per target), largest first. Runs at N = 10 vary a lot
# (lily at 45m: sd 0.2 between runs of one guide on one target), so 2 runs per target cannot
# order rounds 0.03 apart: lily's rounds 2 and 3 scored 0.447 and 0.421 at 2 runs, and the
# four disjoint pairs of 8 runs gave round 2 - round 3 from -0.055 to +0.098; at 8 runs,
# 0.015 +- 0.024 (round 2 - round 4: 0.062 +- 0.025). Validation is cheap (3 s a round)
VAL_CHOICES = ((12, 8), (12, 4), (12, 2), (8, 2), (6, 1), (4, 1), (2, 1), (1, 1))
CURVE_REPEATS = 2  # the curve's runs per target at most (its unguided N = 1000 are dear)
# tune grids (choice temperatures, ESS thresholds), largest first; the first is `ngpmc
# tune`'s default. Choice temperatures 0.1 and 0.05: the 3D vines guide tuned to 0.2 scored
# 0.625 on held-out volumes (N = 10, 8 runs each), 0.643 at 0.1, 0.648 at 0.05 (T = 0.5).
# The widest also ESS 0.2 (resampling only when the weights are very uneven):
# stochastic_plant's guide at Tc 0.3 scored 0.203, 0.224 and 0.246 on 48 envelopes at
# none, 0.5 and 0.2 (experiments/notes/envelope_training.md); none stays (the bush and the
# lazy canopy chose it). The smaller grids are the earlier ones: a budget that fits only
# them plans as before.
TUNE_CHOICES: tuple[tuple[tuple[float, ...], tuple[float | None, ...]], ...] = (
    ((1.0, 0.7, 0.5, 0.3, 0.2, 0.1, 0.05), (None, 0.5, 0.2)),
    ((1.0, 0.7, 0.5, 0.3, 0.2, 0.1, 0.05), (None, 0.5)),
    ((1.0, 0.7, 0.5, 0.3, 0.2), (None, 0.5)),
    ((1.0, 0.5, 0.3), (None,)),
)
CURVE_GUIDED = (1, 3, 10, 30)
CURVE_UNGUIDED = (10, 30, 100, 300, 1000)
# shares of the budget each evaluation stage may take
VAL_SHARE, TUNE_SHARE, CURVE_SHARE = 0.10, 0.10, 0.08


@dataclass(frozen=True)
class Costs:
    """Seconds on one worker: per particle of a trace job (unguided, guided), and of one
    guided run at N = VAL_N (validation, tuning, the curve), each 0 until measured."""

    unguided: float
    guided: float = 0.0  # 0: GUIDED_FACTOR x unguided
    val_run: float = 0.0  # 0: SMALL_N x VAL_N x guided
    train: float = TRAIN_SECONDS  # training seconds per trace
    workers: int = 1
    sets: int = 2  # validation sets

    def per_particle(self, guided: bool) -> float:
        return (self.guided or GUIDED_FACTOR * self.unguided) if guided else self.unguided

    def trace(self, n: int, guided: bool) -> float:
        """Seconds of one trace job of n particles."""
        return n * self.per_particle(guided)

    def run(self, n: int, guided: bool) -> float:
        """Seconds of one evaluation run of n particles (a few cost as VAL_N: overhead)."""
        if not guided:
            return SMALL_N * max(n, VAL_N) * self.unguided
        unit = self.val_run or GUIDED_SMALL_N * VAL_N * self.per_particle(True)
        return unit * max(n, VAL_N) / VAL_N

    def runs(self, k: int, repeats: int, ns: tuple[int, ...], guided: bool) -> float:
        """Wall seconds of runs at each N of `ns` on k targets of every set, `repeats` each."""
        total = sum(self.run(n, guided) for n in ns)
        return self.sets * k * repeats * total / max(1, self.workers)


@dataclass(frozen=True)
class Plan:
    budget: float  # seconds planned for (what was left when planning)
    unguided_particles: int
    guided_particles: int
    traces: int  # round 0's kept traces, all training directories together
    rounds: int  # guided rounds after round 0
    guided_traces: int  # kept traces per guided round
    val_targets: int  # per validation set
    val_repeats: int
    choice_temperatures: tuple[float, ...]  # the tune grid; () = no tuning
    ess: tuple[float | None, ...]
    curve_guided: tuple[int, ...]
    curve_unguided: tuple[int, ...]
    estimates: dict[str, float] = field(default_factory=dict)  # stage -> seconds
    reasons: tuple[str, ...] = ()
    total: float = 0.0  # the run's --budget when planned (0: not recorded)
    # rounds after the `rounds` guided ones: (traces, particles) each, a stronger teacher
    more: tuple[tuple[int, int], ...] = ()

    @property
    def last_round(self) -> int:
        return self.rounds + len(self.more)

    def round_settings(self, r: int) -> tuple[int, int]:
        """(traces, teacher particles) of guided round r >= 1."""
        if r <= self.rounds or not self.more:
            return self.guided_traces, self.guided_particles
        return self.more[min(r - self.rounds, len(self.more)) - 1]


def validation_seconds(costs: Costs, k: int, repeats: int) -> float:
    """Scoring one guide at N = VAL_N (the unguided baseline is run once, not counted)."""
    return STAGE_SECONDS + costs.runs(k, repeats, (VAL_N,), True)


def round_seconds(
    costs: Costs, traces: int, particles: int, guided: bool, trained_on: int, val: float
) -> float:
    """One round: its traces, training on `trained_on` traces, scoring the guide."""
    record = traces * costs.trace(particles, guided) / max(1, costs.workers)
    return record + TRAIN_FIXED + costs.train * trained_on + val


def _validation(costs: Costs, budget: float) -> tuple[int, int, float, str]:
    for k, rep in VAL_CHOICES:
        v = validation_seconds(costs, k, rep)
        if v * (1 + MAX_ROUNDS + MAX_STRONG) <= VAL_SHARE * budget:
            why = f"{k} targets per set, {rep} run(s) each: fits {VAL_SHARE:.0%}"
            if rep > 2:  # the noise the extra runs cut (VAL_CHOICES)
                why += " (runs at N = 10 vary by 0.2: 2 per target cannot order rounds)"
            return k, rep, v, why
    k, rep = VAL_CHOICES[-1]
    return k, rep, validation_seconds(costs, k, rep), f"{k} target per set (the least)"


def _tune(
    val: float, budget: float
) -> tuple[tuple[float, ...], tuple[float | None, ...], float, str]:
    for temps, ess in TUNE_CHOICES:
        g = len(temps) * len(ess)
        if g * val <= TUNE_SHARE * budget:
            return temps, ess, g * val, f"{g} proposal settings: fits {TUNE_SHARE:.0%}"
    return (), (), 0.0, "no tuning: even 3 settings would take over its share"


def _curve(
    costs: Costs, k: int, rep: int, budget: float
) -> tuple[tuple[int, ...], tuple[int, ...], float]:
    """The curve's N: guided and unguided, fewer until they fit their share; guided keeps
    1 and VAL_N (the guide's working N), unguided its two smallest."""
    guided, unguided = list(CURVE_GUIDED), list(CURVE_UNGUIDED)
    rep = min(rep, CURVE_REPEATS)
    droppable = [n for n in reversed(guided) if n not in (1, VAL_N)]  # largest first

    def cost() -> float:
        runs = costs.runs(k, rep, tuple(guided), True) + costs.runs(k, rep, tuple(unguided), False)
        return STAGE_SECONDS * len(guided) + runs

    while cost() > CURVE_SHARE * budget and (droppable or len(unguided) > 2):
        # drop the dearer of the largest droppable guided N and the largest unguided N
        if len(unguided) > 2 and (
            not droppable or costs.run(unguided[-1], False) >= costs.run(droppable[0], True)
        ):
            unguided.pop()
        else:
            guided.remove(droppable.pop(0))
    return tuple(guided), tuple(unguided), cost()


def guided_rounds(
    costs: Costs,
    room: float,
    val: float,
    trained: int,
    particles: int,
    keep_particles: bool = False,
    least: int = MIN_TRACES,
) -> tuple[int, int, int, float] | None:
    """The guided rounds that fit `room` seconds after `trained` traces: (rounds, traces per
    round, particles, seconds) with the most rounds of at least `least` traces, at
    `particles` or, when none fits and not `keep_particles`, at a half or a quarter of
    them; None when none fits."""
    options = sorted(
        {particles, max(MIN_PARTICLES, particles // 2), max(MIN_PARTICLES, particles // 4)},
        reverse=True,
    )
    if keep_particles:
        options = [particles]
    for pg in options:
        per_job = costs.trace(pg, True) / max(1, costs.workers)
        for rounds in range(MAX_ROUNDS, 0, -1):
            fixed = rounds * (TRAIN_FIXED + val + costs.train * trained)
            per_trace = rounds * per_job + costs.train * rounds * (rounds + 1) / 2
            n = min(MAX_TRACES, int((room - fixed) / per_trace))
            if n >= least:
                return rounds, n, pg, fixed + n * per_trace
    return None


def strong_rounds(
    costs: Costs, room: float, val: float, trained: int, least: int = MIN_TRACES
) -> tuple[int, int, int, float] | None:
    """The rounds with a stronger teacher that fill `room` seconds after rounds trained on
    `trained` traces: (rounds, traces per round, particles, seconds). At STRONG_PARTICLES
    (else GUIDED_PARTICLES), the number of rounds (at most MAX_STRONG) that records the most
    traces, each of `least` to MAX_STRONG_TRACES (fewer rounds when equal: each trains on
    every trace again); when MAX_STRONG rounds of MAX_STRONG_TRACES leave time, more
    particles (up to MAX_PARTICLES) fill it. None when not one round of `least` fits."""
    w = max(1, costs.workers)
    for pg in (STRONG_PARTICLES, GUIDED_PARTICLES):
        best: tuple[int, int, float] | None = None
        for k in range(1, MAX_STRONG + 1):
            fixed = k * (TRAIN_FIXED + val + costs.train * trained)
            per_trace = k * costs.trace(pg, True) / w + costs.train * k * (k + 1) / 2
            n = min(MAX_STRONG_TRACES, int((room - fixed) / per_trace))
            if n >= least and (best is None or k * n > best[0] * best[1]):
                best = (k, n, fixed + n * per_trace)
        if best is None:
            continue
        k, n, secs = best
        if k == MAX_STRONG and n == MAX_STRONG_TRACES:
            unit = k * n * costs.trace(1, True) / w  # seconds of one more particle
            add = max(0, min(MAX_PARTICLES - pg, int((room - secs) / unit)))
            pg, secs = pg + add, secs + add * unit
        return k, n, pg, secs
    return None


NO_MORE: tuple[tuple[tuple[int, int], ...], float, str] = ((), 0.0, "")


def _more(
    costs: Costs, room: float, val: float, trained: int, least: int = MIN_TRACES
) -> tuple[tuple[tuple[int, int], ...], float, str]:
    """Plan.more for `room` seconds (strong_rounds), its seconds and why."""
    s = strong_rounds(costs, room, val, trained, least)
    if s is None:
        return NO_MORE
    k, n, pg, secs = s
    why = (
        f"then {k} round(s) of {n} traces with a stronger teacher ({pg} guided particles) "
        f"fill the {room:.0f} s the capped rounds leave"
    )
    return ((n, pg),) * k, secs, why


def _traces(costs: Costs, budget: float, val: float) -> tuple[int, int, int, int, int, float, str]:
    """(rounds, round 0's traces, guided traces per round, unguided particles, guided
    particles, seconds, why): round 0 takes up to ROUND0_SHARE of `budget`, the guided
    rounds the rest; without room for a guided round, round 0 takes it all."""
    p0 = UNGUIDED_PARTICLES

    def most(room: float, p: int) -> int:
        per = costs.trace(p, False) / max(1, costs.workers) + costs.train
        return min(MAX_TRACES, int(max(0.0, room - TRAIN_FIXED - val) / per))

    n0 = max(MIN_TRACES, most(ROUND0_SHARE * budget, p0))
    first = round_seconds(costs, n0, p0, False, n0, val)
    g = guided_rounds(costs, budget - first, val, n0, GUIDED_PARTICLES)
    if g is not None:
        rounds, ng, pg, secs = g
        why = (
            f"round 0: {n0} traces ({ROUND0_SHARE:.0%} of the time for traces); "
            f"{rounds} guided round(s) of {ng} traces at {pg} particles: more rounds would "
            f"have fewer than {MIN_TRACES}"
        )
        return rounds, n0, ng, p0, pg, first + secs, why
    n0 = most(budget, p0)
    while n0 < FEW_TRACES and p0 > MIN_PARTICLES:  # a small budget: fewer particles
        p0 = max(MIN_PARTICLES, p0 // 2)
        n0 = most(budget, p0)
    n0 = max(2, n0)
    why = (
        f"no guided round: one round of {n0} traces at {p0} particles is what fits "
        f"(a guided round needs {MIN_TRACES} traces)"
    )
    pg = min(GUIDED_PARTICLES, p0)
    return 0, n0, n0, p0, pg, round_seconds(costs, n0, p0, False, n0, val), why


def plan(budget: float, costs: Costs) -> Plan:
    """The plan for `budget` seconds at `costs`: evaluation first sized to its shares, the
    rest to traces and training (the most guided rounds whose rounds keep MIN_TRACES)."""
    k, rep, val, why_val = _validation(costs, budget)
    temps, ess, tune_s, why_tune = _tune(val, budget)
    cg, cu, curve_s = _curve(costs, k, rep, budget)
    left = max(0.0, budget - tune_s - curve_s)
    rounds, n, ng, p0, pg, trace_s, why_traces = _traces(costs, left, val)
    more, more_s, why_more = NO_MORE
    if rounds:
        more, more_s, why_more = _more(costs, left - trace_s, val, n + rounds * ng)
    if why_more:
        why_traces += f"; {why_more}"
    reasons = (
        f"validation: {why_val}",
        f"rounds: {why_traces}",
        f"tune: {why_tune}",
        f"curve: guided N {', '.join(map(str, cg))}; unguided N {', '.join(map(str, cu))}",
    )
    return Plan(
        budget=budget,
        unguided_particles=p0,
        guided_particles=pg,
        traces=n,
        rounds=rounds,
        guided_traces=ng,
        val_targets=k,
        val_repeats=rep,
        choice_temperatures=temps,
        ess=ess,
        curve_guided=cg,
        curve_unguided=cu,
        estimates={"rounds": trace_s, "more rounds": more_s, "tune": tune_s, "curve": curve_s},
        reasons=reasons,
        more=more,
    )


def replan(p: Plan, left: float, costs: Costs, trained: int) -> Plan:
    """After round 0, with measured guided costs: the tune grid and the curve sized anew to
    their shares of the plan's budget, then the guided rounds that fit what is `left`."""
    val = validation_seconds(costs, p.val_targets, p.val_repeats)
    temps, ess, tune_s, why_tune = _tune(val, p.budget)
    cg, cu, curve_s = _curve(costs, p.val_targets, p.val_repeats, p.budget)
    room = left - tune_s - curve_s
    g = guided_rounds(costs, room, val, trained, GUIDED_PARTICLES)
    rounds, ng, pg, secs = g if g is not None else (0, 0, p.guided_particles, 0.0)
    more, more_s, why_more = NO_MORE
    if g is None:
        why = f"no guided round: one of {MIN_TRACES} traces would not fit the time left"
    else:
        why = f"{rounds} guided round(s) of {ng} traces at {pg} particles (measured costs)"
        more, more_s, why_more = _more(costs, room - secs, val, trained + rounds * ng)
        why += f"; {why_more}" if why_more else ""
    return replace(
        p,
        rounds=rounds,
        guided_traces=ng,
        guided_particles=pg,
        choice_temperatures=temps,
        ess=ess,
        curve_guided=cg,
        curve_unguided=cu,
        estimates={"rounds": secs, "more rounds": more_s, "tune": tune_s, "curve": curve_s},
        reasons=(*p.reasons, f"after round 0: {why}; tune: {why_tune}"),
        more=more,
    )


def extend(
    p: Plan,
    total: float,
    left: float,
    costs: Costs,
    done: int,
    trained: int,
    val: float,
    fixed: bool = False,
    curve_done: bool = False,
) -> Plan:
    """A rerun under a larger budget `total` with `left` seconds of it: the plan `p` of the
    run before, its first `done` guided rounds finished (trained on `trained` traces), then
    the guided rounds that fit after tuning and the curve again, at the measured `costs`
    (`val`: one round's validation seconds as measured). Validation and the curve keep
    their settings (the rounds and guides compare with the old); a plan without a tune grid
    gets the one that fits its share of `total`. `fixed`: keep `p.guided_particles` (a cut
    round resumes its traces with them); `curve_done`: the unguided curve runs are cached,
    only the guided ones count. A round needs MIN_TRACES traces, or as many as the rounds
    before trained on when they were fewer (a small first run: a round that doubles the
    data is worth its validation), and FEW_TRACES at least."""
    if p.choice_temperatures:
        temps, ess = p.choice_temperatures, p.ess
        tune_s = len(temps) * len(ess) * val
        why_tune = f"the grid of the run before ({len(temps) * len(ess)} settings)"
    else:
        temps, ess, tune_s, why_tune = _tune(val, total)
    k, rep = p.val_targets, min(p.val_repeats, CURVE_REPEATS)
    curve_s = STAGE_SECONDS * len(p.curve_guided) + costs.runs(k, rep, p.curve_guided, True)
    if not curve_done:
        curve_s += costs.runs(k, rep, p.curve_unguided, False)
    particles = p.round_settings(done + 1)[1] if fixed else GUIDED_PARTICLES
    least = min(MIN_TRACES, max(FEW_TRACES, trained))  # or as many as trained on so far
    room = left - tune_s - curve_s
    g = guided_rounds(costs, room, val, trained, particles, fixed, least)
    more, more_s, why_more = NO_MORE
    if g is None:
        rounds, ng, pg, secs = 0, p.guided_traces, p.guided_particles, 0.0
        why = (
            f"no guided round added: one of {least} traces, tuning and the curve would "
            f"not fit the {left:.0f} s left"
        )
    else:
        rounds, ng, pg, secs = g
        why = (
            f"{rounds} guided round(s) added after round {done}, {ng} traces each at {pg} "
            f"particles (measured costs; {left:.0f} s left)"
        )
        more, more_s, why_more = _more(costs, room - secs, val, trained + rounds * ng, least)
        why += f"; {why_more}" if why_more else ""
    return replace(
        p,
        budget=left,
        total=total,
        rounds=done + rounds,
        guided_traces=ng,
        guided_particles=pg,
        choice_temperatures=temps,
        ess=ess,
        estimates={"rounds": secs, "more rounds": more_s, "tune": tune_s, "curve": curve_s},
        reasons=(*p.reasons, f"budget {total:.0f} s: {why}; tune: {why_tune}"),
        more=more,
    )


def fill(
    p: Plan, left: float, costs: Costs, trained: int, val: float, reserve: float
) -> Plan | None:
    """After the plan's last round, `left` seconds of the budget left: the plan with the
    strong rounds that fit them beside the `reserve` (tuning, the curve) at the measured
    costs (`val`: one round's validation seconds); None when not one fits."""
    room = left - reserve
    more, secs, why = _more(costs, room, val, trained)
    if not more:
        return None
    n, pg = more[0]
    return replace(
        p,
        more=p.more + more,
        estimates={**p.estimates, "more rounds": secs},
        reasons=(
            *p.reasons,
            f"after round {p.last_round}: {len(more)} round(s) of {n} traces with {pg} "
            f"guided particles fit the {room:.0f} s left before tuning and the curve "
            "(measured costs)",
        ),
    )


def reserve_seconds(p: Plan, costs: Costs, val: float, curve_done: bool = False) -> float:
    """Seconds to keep for tuning and the curve at the measured `costs` (`val`: one
    round's validation seconds as the last round measured it; `curve_done`: the unguided
    curve runs are cached). The plan's own estimates are made from round 0's validation,
    whose first guided runs also load the guide and its kernels: 4x too high (bush: 267 s
    planned for a tuning that took 20 s)."""
    tune = len(p.choice_temperatures) * len(p.ess) * val
    k, rep = p.val_targets, min(p.val_repeats, CURVE_REPEATS)
    curve = STAGE_SECONDS * len(p.curve_guided) + costs.runs(k, rep, p.curve_guided, True)
    if not curve_done:
        curve += costs.runs(k, rep, p.curve_unguided, False)
    return tune + curve


def traces_that_fit(costs: Costs, particles: int, trained: int, val: float, room: float) -> int:
    """Guided traces of `particles` particles one round can record in `room` seconds and
    still train on them beside the `trained` traces before it and score its guide."""
    per = costs.trace(particles, True) / max(1, costs.workers) + costs.train
    left = room - TRAIN_FIXED - costs.train * trained - val
    return max(0, int(left / per)) if per > 0 else 0


def train_per_trace(seconds: float, traces: int) -> float:
    """Training seconds per trace from one training on `traces` traces that took `seconds`:
    what it took beyond TRAIN_FIXED, per trace (at least a twentieth of TRAIN_SECONDS); the
    guess TRAIN_SECONDS when fewer than FEW_TRACES traces cannot tell it from the fixed
    part."""
    if traces < FEW_TRACES:
        return TRAIN_SECONDS
    return max(TRAIN_SECONDS / 20, (seconds - TRAIN_FIXED) / traces)


def trace_allowance(planned: float, left: float, reserve: float) -> float:
    """Seconds a round may spend on traces before it trains on what it has: TRACE_SLACK
    times the `planned` seconds plus TRACE_GRACE, but never into the `reserve` (its
    training and validation, tuning, the curve) of the `left` seconds."""
    return max(0.0, min(TRACE_SLACK * planned + TRACE_GRACE, left - reserve))


def parse_budget(text: str) -> float:
    """'45m', '2h', '90s', '1h30m' or plain seconds -> seconds (at most MAX_BUDGET);
    ValueError otherwise."""
    t = text.strip().lower()
    units = {"h": 3600.0, "m": 60.0, "s": 1.0}
    if t.replace(".", "", 1).isdigit():
        seconds = float(t)
    else:
        seconds, number = 0.0, ""
        for ch in t:
            if ch.isdigit() or ch == ".":
                number += ch
            elif ch in units and number:
                seconds += float(number) * units[ch]
                number = ""
            else:
                raise ValueError(f"not a duration: {text!r}")
        if number or not t:
            raise ValueError(f"not a duration: {text!r}")
    if not 0 < seconds <= MAX_BUDGET:  # nan fails too
        raise ValueError(f"not a duration from 1 s to 7 days: {text!r}")
    return seconds
