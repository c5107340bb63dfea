"""SMC mechanics: determinism, batching, resampling, traces, features, failures, options."""

import numpy as np
import pytest
from fixtures.tiny_programs import SumXLikelihood, discrete_program, make_program
from ngpm_runtime.errors import NgpmError, ProgramError, SMCFailed
from ngpm_runtime.image import features as features_module
from ngpm_runtime.image.raster import rasterize
from ngpm_runtime.inference.likelihood import Likelihood, NullLikelihood, ShapeLikelihood
from ngpm_runtime.inference.proposals import PriorProposal
from ngpm_runtime.inference.resample import SCHEMES, resample
from ngpm_runtime.inference.smc import (
    SiteOrder,
    SMCObserver,
    SMCOptionError,
    SMCOptions,
    SMCState,
    TraceRecording,
    forward,
    replay,
    smc,
)
from ngpm_runtime.program import Site


def disk_mask(size: int = 50) -> np.ndarray:
    yy, xx = np.mgrid[0:size, 0:size]
    return (xx - 24.5) ** 2 + (yy - 20) ** 2 < 16**2


START = (0.0, -16.0, 90.0)  # bottom of the disk in vines' viewport, heading up


def run_vines(vines, n=60, seed=0, proposal=None, observers=(), **kw):
    like = ShapeLikelihood(disk_mask(), vines.viewport)
    options = SMCOptions(seed=seed, start=START, target_mask=disk_mask(), **kw)
    return smc(vines, like, n, proposal, options, observers)


def test_seeded_runs_are_bit_identical(vines) -> None:
    a = run_vines(vines, seed=4)
    b = run_vines(vines, seed=4)
    assert [p.primitives for p in a.particles] == [p.primitives for p in b.particles]
    assert np.array_equal(a.log_weights, b.log_weights)
    assert a.log_evidence == b.log_evidence and a.ess_history == b.ess_history
    c = run_vines(vines, seed=5)
    assert [p.primitives for p in a.particles] != [p.primitives for p in c.particles]


def test_result_fields(vines) -> None:
    r = run_vines(vines)
    assert len(r.particles) == 60 and r.log_weights.shape == (60,)
    assert len(r.ess_history) == r.steps and r.seconds > 0
    assert all(0 < e <= 60 + 1e-9 for e in r.ess_history)
    assert np.isfinite(r.log_evidence)
    score = [p.log_prior + p.log_likelihood for p in r.particles]
    assert r.best.log_prior + r.best.log_likelihood == max(score)
    assert {p.status for p in r.particles} <= {"done", "limit", "dead"}


def test_likelihood_increments_sum_to_full_loglik(vines) -> None:
    like = ShapeLikelihood(disk_mask(), vines.viewport)
    r = run_vines(vines, n=30, seed=2)
    for p in r.particles[:10]:
        img = rasterize(p.primitives, vines.viewport, 50, 50)
        from ngpm_runtime.geometry.turtle import prim_bbox

        boxes = np.array([prim_bbox(q) for q in p.primitives])
        bbox = np.array(
            [boxes[:, 0].min(), boxes[:, 1].min(), boxes[:, 2].max(), boxes[:, 3].max()]
        )
        assert abs(like.full(img, bbox) - p.log_likelihood) < 1e-6


@pytest.mark.parametrize("scheme", sorted(SCHEMES))
def test_resampling_schemes(scheme) -> None:
    rng = np.random.Generator(np.random.PCG64(0))
    w = np.array([0.1, 0.0, 0.5, 0.15, 0.25])
    log_w = np.log(np.where(w > 0, w, 1e-300))
    log_w[1] = -np.inf
    counts = np.zeros(5)
    for _ in range(400):
        idx = resample(scheme, log_w, rng, 40)
        assert len(idx) == 40 and np.all(np.diff(idx) >= 0)
        assert not np.any(idx == 1)
        counts += np.bincount(idx, minlength=5)
    np.testing.assert_allclose(counts / counts.sum(), w, atol=0.01)
    # low-variance schemes: systematic counts are within 1 of n * w, stratified within 2,
    # residual keeps at least floor(n * w) copies
    for _ in range(50):
        wp = w[[0, 2, 3, 4]]
        dev = np.bincount(resample(scheme, np.log(wp), rng, 20), minlength=4) - 20 * wp
        if scheme == "systematic":
            assert np.all(np.abs(dev) < 1.0 + 1e-9)
        elif scheme == "stratified":
            assert np.all(np.abs(dev) < 2.0 + 1e-9)
        elif scheme == "residual":
            assert np.all(dev > -1.0 + 1e-9)


class Counting(PriorProposal):
    def __init__(self) -> None:
        self.calls: list[tuple[int, int]] = []

    def propose(self, site, args, features, rng):
        self.calls.append((site.index, len(args)))
        return super().propose(site, args, features, rng)


def test_one_batched_proposal_call_per_site_per_round(vines) -> None:
    q = Counting()
    r = smc(vines, None, 200, q, options=SMCOptions(seed=1, start=START))
    visits = sum(n for _, n in q.calls)
    assert r.steps > 1 and q.calls[0] == (0, 200)  # every particle's start angle at once
    # one call per particle visit would make `visits` calls
    assert len(q.calls) < visits / 8


def test_all_zero_weight_raises_smcfailed(vines) -> None:
    class Impossible(Likelihood):
        needs_canvas = False

        def start(self, n):
            return {}

        def increment(self, state, canvas, draw):
            return np.full(len(draw.idx), -np.inf)

    with pytest.raises(SMCFailed) as err:
        smc(vines, Impossible(), 20, options=SMCOptions(start=START))
    assert "\n" not in str(err.value) and isinstance(err.value, NgpmError)


def test_nan_increments_are_zero_weight_not_nan(vines) -> None:
    class HalfNaN(Likelihood):
        needs_canvas = False

        def start(self, n):
            return {}

        def increment(self, state, canvas, draw):
            out = np.zeros(len(draw.idx))
            out[draw.idx % 2 == 1] = np.nan
            return out

    r = smc(vines, HalfNaN(), 20, options=SMCOptions(start=START, ess_threshold=0.1))
    assert not np.isnan(r.log_weights).any() and np.isfinite(r.log_evidence)
    assert not any(np.isnan(p.log_likelihood) for p in r.particles)


def test_record_trace_replays_best_particle(vines) -> None:
    r = run_vines(vines, n=40, seed=3, trace=TraceRecording.FULL)
    trace = r.best.trace
    assert trace and all(isinstance(f, np.ndarray) and f.dtype == np.float32 for _, f, _ in trace)
    fm = features_module.FeatureMaker(vines, vines.viewport, disk_mask(), context=True, far=True)
    for s, f, _ in trace:
        assert f.shape == (fm.n_features(vines.sites[s]),)
    assert trace[0][0] == 0  # the start angle comes first
    # start pose: x = 0 -> 0 in [-1, 1]; y = -16 -> (-16 + 22) / 24 * 2 - 1
    np.testing.assert_allclose(trace[0][1][:2], [0.0, 12 / 24 - 1.0], atol=1e-6)

    values = [(s, v) for s, _, v in trace]

    class Replay(PriorProposal):
        def propose(self, site, args, features, rng):
            s, v = values.pop(0)
            assert s == site.index and len(args) == 1
            return np.array([v]), np.zeros(1)

    again = smc(vines, None, 1, Replay(), options=SMCOptions(start=START)).particles[0]
    assert again.primitives == r.best.primitives and not values
    assert abs(again.log_prior - r.best.log_prior) < 1e-9


def test_features_are_computed_only_when_needed(vines, monkeypatch) -> None:
    class Boom:
        def __init__(self, *a, **k):
            raise AssertionError("FeatureMaker built without need")

    monkeypatch.setattr(features_module, "FeatureMaker", Boom)
    run_vines(vines, n=10)
    with pytest.raises(AssertionError):
        run_vines(vines, n=10, trace=TraceRecording.FULL)


def test_proposal_with_features_gets_them(vines) -> None:
    seen = []

    class Featured(PriorProposal):
        uses_features = True

        def propose(self, site, args, features, rng):
            assert features is not None and features.shape[0] == len(args)
            assert features.dtype == np.float32
            seen.append((site.index, features.shape[1], len(args)))
            return super().propose(site, args, features, rng)

    result = run_vines(vines, n=10, proposal=Featured())
    from ngpm_runtime.image.features import FeatureMaker

    fm = FeatureMaker(vines, vines.viewport, disk_mask())
    # one call per site served, with every waiting particle's row of the site's full width
    assert len({i for i, _, _ in seen}) >= 3
    assert all(width == fm.n_features(vines.sites[i]) for i, width, _ in seen)
    assert all(1 <= rows <= 10 for _, _, rows in seen)
    assert result.steps > 1 and len(seen) >= result.steps


def test_forward_without_viewport_and_null_likelihood(vines) -> None:
    prog = make_program({"A": lambda ctx: [("F", 1.0), ("@O", 0.5)]})
    f = forward(prog)
    assert f.primitives == [("seg", 0.0, 0.0, 1.0, 0.0, 1.0), ("disk", 1.0, 0.0, 0.5)]
    assert f.status == "done" and f.log_weight == 0.0 and f.trace is None
    r = smc(vines, NullLikelihood(), 5, options=SMCOptions(start=START))
    assert r.log_evidence == 0.0
    r = smc(make_program({"A": lambda ctx: [("F", 1.0)]}), NullLikelihood(), 3)
    assert all(p.primitives == [("seg", 0.0, 0.0, 1.0, 0.0, 1.0)] for p in r.particles)

    class NeedsCanvas(Likelihood):
        def start(self, n):
            return {}

        def increment(self, state, canvas, draw):
            return np.zeros(len(draw.idx))

    with pytest.raises(ProgramError, match="viewport"):
        smc(prog, NeedsCanvas(), 5)


def test_ess_threshold_resamples_less() -> None:
    like = SumXLikelihood(2.0, 3.0)
    every = smc(discrete_program(), like, 100, options=SMCOptions(seed=1))
    some = smc(discrete_program(), like, 100, options=SMCOptions(seed=1, ess_threshold=0.5))
    assert every.info["resamples"] == every.steps - 1  # not after the last step
    assert some.info["resamples"] < some.steps - 1


def test_ess_threshold_defaults_to_the_proposals_settings() -> None:
    """A proposal with `settings.ess_threshold` (a tuned Guide) sets when SMC resamples,
    unless the caller says otherwise."""

    class Tuned(PriorProposal):
        class settings:
            ess_threshold = 0.5

    like = SumXLikelihood(2.0, 3.0)
    tuned = smc(
        discrete_program(), like, 100, Tuned(), options=SMCOptions(ess_from_proposal=True, seed=1)
    )
    want = smc(
        discrete_program(),
        like,
        100,
        PriorProposal(),
        options=SMCOptions(seed=1, ess_threshold=0.5),
    )
    every = smc(
        discrete_program(), like, 100, Tuned(), options=SMCOptions(seed=1, ess_threshold=None)
    )
    assert tuned.info["resamples"] == want.info["resamples"] < tuned.steps - 1
    assert np.array_equal(tuned.log_weights, want.log_weights)
    assert every.info["resamples"] == every.steps - 1


def test_options_are_checked() -> None:
    prog = discrete_program()
    with pytest.raises(SMCOptionError):
        smc(prog, None, 0)
    with pytest.raises(SMCOptionError):
        smc(prog, None, 5, options=SMCOptions(resample="bogus"))
    with pytest.raises(SMCOptionError):
        smc(prog, None, 5, options=SMCOptions(ess_threshold=1.5))
    with pytest.raises(SMCOptionError, match="'often'"):
        smc(prog, None, 5, options=SMCOptions(ess_threshold="often"))
    with pytest.raises(SMCOptionError, match="not both"):
        smc(prog, None, 5, options=SMCOptions(ess_threshold=0.5, ess_from_proposal=True))
    with pytest.raises(SMCOptionError, match="TraceRecording"):
        smc(prog, None, 5, options=SMCOptions(trace=True))
    with pytest.raises(SMCOptionError, match="differ"):
        smc(prog, None, 5, options=SMCOptions(target_mask=np.zeros((40, 40), bool)))


def test_errors_in_generated_code_surface_from_smc() -> None:
    def produce_a(ctx):
        import math

        return [("F", math.log(0.0))]

    with pytest.raises(ProgramError, match=r"bad\.lsys:3"):
        smc(
            make_program({"A": produce_a}, source="bad.lsys", locations={"production A": (3, 1)}),
            SumXLikelihood(),
            10,
        )


def test_finished_particles_wait() -> None:
    # particles finish after 1..3 primitives; all of them end "done" with their weights
    r = smc(
        discrete_program(),
        SumXLikelihood(2.0, 1.0),
        300,
        options=SMCOptions(seed=2, ess_threshold=0.2),
    )
    lengths = {len(p.primitives) for p in r.particles}
    assert len(lengths) > 1 and all(p.status == "done" for p in r.particles)


def test_particles_that_draw_nothing_get_the_blank_loglik(vines) -> None:
    from ngpm_runtime.program import Site

    sites = [Site(index=0, id="A/choice", kind="categorical", k=2, probs=(0.5, 0.5))]

    def produce_a(ctx):
        return [("F", 4.0)] if ctx.choose(0, (0.5, 0.5)) == 0 else []

    prog = make_program({"A": produce_a}, sites=sites, viewport=vines.viewport, start=START)
    like = ShapeLikelihood(disk_mask(), vines.viewport)
    r = smc(prog, like, 40, options=SMCOptions(seed=0, ess_threshold=0.01))
    blank = like.full(
        np.zeros((50, 50), dtype=np.uint8), np.array([np.inf, np.inf, -np.inf, -np.inf])
    )
    empties = [p for p in r.particles if not p.primitives]
    assert empties and all(p.log_likelihood == blank for p in empties)
    assert blank < -1000  # eq. 1 of an empty image: far from the target


def test_resampling_properties() -> None:
    from hypothesis import given, settings
    from hypothesis import strategies as st

    weights = st.lists(st.floats(0.0, 1e3), min_size=1, max_size=30).filter(lambda w: sum(w) > 1e-6)

    @settings(max_examples=60, deadline=None)
    @given(
        w=weights,
        n=st.integers(1, 50),
        scheme=st.sampled_from(sorted(SCHEMES)),
        seed=st.integers(0, 2**31),
    )
    def check(w, n, scheme, seed):
        w = np.array(w)
        with np.errstate(divide="ignore"):
            idx = resample(scheme, np.log(w), np.random.Generator(np.random.PCG64(seed)), n)
        assert len(idx) == n and np.all(np.diff(idx) >= 0)
        assert np.all(w[idx] > 0)
        if scheme == "residual":
            counts = np.bincount(idx, minlength=len(w))
            assert np.all(counts >= np.floor(n * w / w.sum() + 1e-9) - 1)

    check()


def test_infinite_weight_raises_smcfailed() -> None:
    class Liar(PriorProposal):
        def propose(self, site, args, features, rng):
            v, _ = super().propose(site, args, features, rng)
            return v, np.full(len(v), -np.inf)

    with pytest.raises(SMCFailed, match=r"\+inf"):
        smc(discrete_program(), None, 10, Liar())


def test_value_traces_replay_to_the_full_trace(vines) -> None:
    """trace=TraceRecording.VALUES draws what trace=TraceRecording.FULL draws; replaying the best
    particle's values gives its full trace, features and all, bit for bit."""
    full = run_vines(vines, n=30, seed=4, trace=TraceRecording.FULL)
    vals = run_vines(vines, n=30, seed=4, trace=TraceRecording.VALUES)
    assert vals.best.primitives == full.best.primitives
    assert [(s, v) for s, _, v in vals.best.trace] == [(s, v) for s, _, v in full.best.trace]
    assert all(f is None for _, f, _ in vals.best.trace)
    again = replay(
        vines, [(s, v) for s, _, v in vals.best.trace], start=START, target_mask=disk_mask()
    )
    assert again.primitives == full.best.primitives
    assert again.log_prior == pytest.approx(full.best.log_prior, abs=1e-9)
    assert len(again.trace) == len(full.best.trace)
    for (s1, f1, v1), (s2, f2, v2) in zip(again.trace, full.best.trace, strict=True):
        assert s1 == s2 and v1 == v2 and np.array_equal(f1, f2)


def test_replay_rejects_wrong_values(vines) -> None:
    trace = run_vines(vines, n=5, trace=TraceRecording.VALUES)
    values = [(s, v) for s, _, v in trace.best.trace]
    with pytest.raises(ProgramError, match="recorded site"):
        replay(vines, [(values[0][0] + 1, values[0][1])] + values[1:], start=START)
    with pytest.raises(ProgramError, match="after the"):
        replay(vines, values[:-1], start=START)
    with pytest.raises(ProgramError, match="used"):
        replay(vines, values + [(0, 0.0)], start=START)
    with pytest.raises(SMCOptionError):
        run_vines(vines, n=5, trace="features")


def test_site_order_serves_sites_no_other_waiting_site_leads_to() -> None:
    order = SiteOrder()
    waiting = {1: [0], 2: [1, 2, 3], 3: [4]}
    assert order.pick(waiting) == 2  # nothing learned yet: most waiting particles
    order.saw(1, 2)
    order.saw(2, 3)
    assert order.pick(waiting) == 1  # 1 leads to 2 and 3: serve it first
    assert order.pick({2: [0], 3: [1, 2]}) == 2
    order.saw(3, 3)  # a site that follows itself is not blocked by itself
    assert order.pick({3: [0], 4: [1, 2]}) == 4
    assert order.pick({3: [0, 1], 4: [2]}) == 3
    order.saw(3, 1)  # a cycle 1 -> 2 -> 3 -> 1: every site blocked, most waiting first
    assert order.pick({1: [0], 3: [1, 2]}) == 3
    assert order.pick({1: [0, 1], 3: [2]}) == 1
    assert order.pick({5: [0], 4: [1]}) == 4  # ties: the lowest site index


def test_greedy_batching_makes_fewer_calls(vines) -> None:
    """Vines asks for its sites in chains within a step; the greedy order serves each site
    about once per step."""
    calls = []

    class Counting(PriorProposal):
        def propose(self, site, args, features, rng):
            calls.append(site.index)
            return super().propose(site, args, features, rng)

    r = run_vines(vines, n=40, seed=1, proposal=Counting())
    assert len(calls) <= 7.5 * r.steps  # 7.1 here; serving every waiting site: 8.0


def test_site_order_closure_matches_brute_force() -> None:
    rng = np.random.default_rng(5)
    order = SiteOrder()
    edges: set[tuple[int, int]] = set()
    for _ in range(60):
        a, b = (int(x) for x in rng.integers(0, 12, 2))
        order.saw(a, b)
        edges.add((a, b))
        reach = {x: set() for x in range(12)}
        for _ in range(12):  # brute force transitive closure
            for x, y in edges:
                reach[x] |= {y} | reach[y]
        for x in range(12):
            assert order.reach.get(x, set()) == reach[x]
        sites = rng.choice(12, size=int(rng.integers(1, 6)), replace=False).tolist()
        waiting = {k: [0] * int(rng.integers(1, 4)) for k in sites}
        free = [k for k in waiting if not any(k in reach[a] for a in waiting if a != k)]
        want = max(free or waiting, key=lambda k: (len(waiting[k]), -k))
        assert order.pick(waiting) == want


class Lineage(SMCObserver):
    """Counts, in a registered per-particle array, the steps each particle drew in."""

    def __init__(self) -> None:
        self.steps = self.resamples = self.values = 0
        self.state: SMCState | None = None

    def site_drawn(self, site, idx, values) -> None:
        self.values += len(values)

    def step_done(self, state: SMCState) -> None:
        self.steps += 1
        self.state = state
        counts = state.arrays.get("draws")
        if counts is None:
            counts = state.register("draws", np.zeros(state.n, dtype=np.int64))
        counts[state.drawn] += 1

    def resampled(self, ancestors) -> None:
        self.resamples += 1


def test_observers_watch_without_changing_the_run(vines) -> None:
    """Same seed, same run with or without observers; registered arrays follow resampling
    (each final particle drew in as many steps as it has primitives)."""
    plain = run_vines(vines, n=20, seed=5)
    obs = Lineage()
    seen = run_vines(vines, n=20, seed=5, observers=[obs])
    assert np.array_equal(seen.log_weights, plain.log_weights)
    assert [p.primitives for p in seen.particles] == [p.primitives for p in plain.particles]
    assert obs.steps == seen.steps and obs.resamples == seen.info["resamples"] > 0
    assert obs.values > 0 and obs.state is not None
    draws = obs.state.arrays["draws"]
    assert draws.tolist() == [len(p.primitives) for p in seen.particles]


def test_an_observer_that_raises_stops_the_run(vines) -> None:
    class Stop(SMCObserver):
        def step_done(self, state: SMCState) -> None:
            if state.steps == 3:
                raise RuntimeError("stop here")

    with pytest.raises(RuntimeError, match="stop here"):
        run_vines(vines, n=5, observers=[Stop()])
    with pytest.raises(SMCOptionError, match="one per particle"):
        SMCState(3, np.zeros(3)).register("x", np.zeros(2))


@pytest.mark.parametrize(
    "case, words",
    [
        ("args", "prior arguments are not numbers of one length"),
        ("arity", "modules of different arity share it"),
    ],
)
def test_rows_that_do_not_fit_a_site_are_one_line_errors(case: str, words: str) -> None:
    """A round with features (its particles' state packed for kernels.unpack_round):
    particles at one site whose prior arguments or module parameters differ in length get
    the ProgramError naming the site, never a traceback."""
    from ngpm_runtime.program import Site

    sites = [
        Site(index=0, id="S/0/bernoulli0", kind="bernoulli", module="S"),
        Site(index=1, id="B/0/normal0", kind="normal", module="B", arity=1),
        Site(index=2, id="B/0/categorical0", kind="categorical", k=2, module="B", arity=1),
    ]

    class Featured(PriorProposal):
        uses_features = True

    def produce_s(ctx):  # the particles differ after this flip
        b = ctx.bernoulli(0, 0.5)
        return [("B", b) if b or case != "arity" else ("B", b, 2.0)]

    def produce_b(ctx, b, *more):
        if case == "args":  # 2 weights or 3
            return [("F", 1.0 + ctx.categorical(2, (1.0, 1.0) if b else (1.0, 1.0, 1.0)))]
        return [("F", ctx.normal(1, 0.0, 1.0))]

    prog = make_program(
        {"S": produce_s, "B": produce_b},
        axiom=(("S",),),
        sites=sites,
        viewport=(-2.0, 2.0, -2.0, 2.0),
    )
    with pytest.raises(ProgramError, match=words):
        smc(prog, None, 20, Featured(), options=SMCOptions(canvas_size=(8, 8)))


def test_a_program_without_sites_records_full_traces() -> None:
    """A grammar with no random choice: full traces (feature rows, the round buffers of no
    site) and a replay of it run; the trace is empty."""
    prog = make_program({}, axiom=(("F", 1.0),) * 3, viewport=(-4.0, 4.0, -4.0, 4.0))
    r = smc(prog, None, 3, options=SMCOptions(trace=TraceRecording.FULL, canvas_size=(8, 8)))
    assert all(p.trace == [] and len(p.primitives) == 3 for p in r.particles)
    assert replay(prog, []).primitives == r.particles[0].primitives


def test_roulette_is_exact_in_expectation() -> None:
    """A live particle below the share plays Russian roulette: it stays with probability
    share / threshold at the threshold's weight, else it is dead; the others stay as they
    are, and its expected weight is what it was."""
    from ngpm_runtime.geometry.derive import Particle
    from ngpm_runtime.inference.smc import Population

    rng = np.random.default_rng(0)
    kept = []
    for _ in range(20000):
        pop = Population([Particle(None, (0.0, 0.0, 0.0, 1.0)) for _ in range(3)])
        pop.live = [1, 2]
        pop.log_w[:] = [0.0, -0.5, -5.0]  # particle 2's share 0.0037, below 0.01
        pop.roulette(rng, np.log(0.01))
        assert pop.log_w[0] == 0.0 and pop.log_w[1] == -0.5
        kept.append(np.exp(pop.log_w[2]))
        assert pop.live == ([1, 2] if kept[-1] else [1])
        assert pop.parts[2].status == ("live" if kept[-1] else "dead")
    kept_a = np.array(kept)
    assert 0.3 < (kept_a > 0).mean() < 0.45  # stays with probability share / 0.01
    assert abs(kept_a.mean() / np.exp(-5.0) - 1) < 0.05


def test_a_runaway_particle_does_not_hold_up_the_run() -> None:
    """Resampling at a low ESS only: a particle that goes on drawing long after the others
    finished, its weight negligible (1e-100 of the total), is dropped by the roulette; it
    used to keep the run going to its cap (a circuit run: 5000 steps instead of ~250)."""
    sites = [Site(index=0, id="A/choice", kind="categorical", k=2, probs=(0.5, 0.5), module="A")]

    def produce_a(ctx):
        return [("F", 1.0)] if ctx.choose(0, (0.5, 0.5)) == 0 else [("F", 1.0), ("B", 0.0)]

    def produce_b(ctx, k):
        return [("F", 1.0), ("B", k + 1)] if k < 300 else []

    class PerPrimitive(Likelihood):  # -300 per primitive: the long ones fall behind fast
        needs_canvas = False

        def start(self, n):
            return {}

        def increment(self, state, canvas, draw):
            return np.full(len(draw.idx), -300.0)

    prog = make_program({"A": produce_a, "B": produce_b}, sites=sites)
    r = smc(prog, PerPrimitive(), 8, options=SMCOptions(seed=3, ess_threshold=0.01))
    lengths = sorted(len(p.primitives) for p in r.particles)
    assert lengths[0] == 1 and r.steps <= 4  # without the roulette: 302 steps
    assert {p.status for p in r.particles} == {"done", "dead"} and r.info["resamples"] == 0
    assert r.best.primitives and len(r.best.primitives) == 1
    again = smc(prog, PerPrimitive(), 8, options=SMCOptions(seed=3, ess_threshold=0.01))
    assert np.array_equal(r.log_weights, again.log_weights)  # seeded: the same
