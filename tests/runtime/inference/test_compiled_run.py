"""Unguided SMC on the compiled deriver (inference/compiled_run.py, geometry/compiled.py)
against the Python deriver, the reference: the same seeded run gives the same particles,
primitives, traces, weights and evidence, bit for bit; an error the kernel cannot decide
like Python is the Python deriver's located error."""

from pathlib import Path

import numpy as np
import pytest
from fixtures.tiny_programs import SumXLikelihood
from ngpm_runtime.bundled import bundled_guide, bundled_program, demo_targets
from ngpm_runtime.errors import ProgramError
from ngpm_runtime.geometry.compiled import compiled_deriver
from ngpm_runtime.geometry.turtle import prim_bbox
from ngpm_runtime.image.raster import rasterize
from ngpm_runtime.inference import smc as smc_module
from ngpm_runtime.inference.likelihood import ShapeLikelihood, circuit_loglik
from ngpm_runtime.inference.smc import SMCOptions, TraceRecording, smc
from repo_paths import REPO

from ngpm_compiler.language.compile import load_grammar

# conditions, stochastic groups, every random call, math, F rewritten, cut, halt, ignored
# modules, default arguments, disks, leaves, turn-around
A_RULE = (
    "A(n, d) : n > 0 --> F(uniform(0.5, 1.5)) [ +(gauss(20, 5) * (1 + d % 2)) B(n - 1) ]"
    " -(categorical(1, 2, 3) * 10) A(n - 1, d + 1) : 0.7"
)
FEATURES = f"""
#define W 0.4
viewport: -12 12 -12 12
derivation length: 9
angle: 30

Axiom: !(W) A(4, 0) Q(2)

production:

{A_RULE}
                   | F(abs(sin(d * 30)) + 0.2) @O(0.3 + flip(0.3) * 0.2) [ f % F ] : 0.3
A(n, d) --> ~l(1 + sqrt(n + 1), 0.5 + min(d, 2) / 4) | + F
B(m) : m > 1 and m < 3 --> F(2 ^ -1) + B(m - 1) X(floor(m * 1.7), atan2(m, 2))
B(m) : m >= 3 --> F [ - F(gauss(1, max(0, m - 3))) ] halt : 0.2 | F F : 0.8
F --> F F(0.5)
"""

# nesting deeper than the arrays' first capacity (64 stack rows, 16 turtle states) and more
# values in one production than the first 8 columns: the kernel grows them and goes on
DEEP = """
viewport: -40 40 -40 40
derivation length: 200

Axiom: D(90)

production:

D(k) : k > 0 --> [ +(gauss(0, 5)) f(0.2) D(k - 1) ] F(0.3) : 0.9 | M F : 0.1
"""
DEEP += "M --> " + " ".join(["+(gauss(0, 1))"] * 10) + " F\n"


def grammar(tmp_path: Path, text: str, name: str = "g.lsys"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return load_grammar(path)


def disk_mask(size: int = 32) -> np.ndarray:
    yy, xx = np.mgrid[:size, :size]
    return (yy - size / 2) ** 2 + (xx - size / 2) ** 2 < (size / 3) ** 2


def both(monkeypatch, program, likelihood, n, proposal=None, **options):
    """The same run on the compiled deriver and on the Python one."""
    out = []
    monkeypatch.setattr(smc_module, "COMPILE_FROM", 1)
    for use in (True, False):
        monkeypatch.setattr(smc_module, "USE_COMPILED", use)
        opts = SMCOptions(**options)
        out.append(smc(program, likelihood, n, proposal, options=opts))
    assert out[0].info.get("deriver") == "compiled"
    assert out[1].info.get("deriver") is None
    return out


def assert_same(a, b) -> None:
    assert a.steps == b.steps
    assert a.log_evidence == b.log_evidence
    assert a.ess_history == b.ess_history
    np.testing.assert_array_equal(a.log_weights, b.log_weights)
    for p, q in zip(a.particles, b.particles, strict=True):
        assert p == q  # primitives, log prior / likelihood / weight, trace, status, limit
    assert a.best == b.best
    for key in ("particle_steps", "resamples", "status", "limits"):
        assert a.info[key] == b.info[key]


def test_vines_runs_equal_python(monkeypatch) -> None:
    program = load_grammar(REPO / "grammars" / "vines.lsys")
    mask = disk_mask()
    like = ShapeLikelihood(mask, program.viewport)
    for seed in range(3):
        a, b = both(
            monkeypatch,
            program,
            like,
            40,
            seed=seed,
            canvas_size=mask.shape,
            target_mask=mask,
            trace=TraceRecording.VALUES,
        )
        assert a.info["resamples"] > 0
        assert_same(a, b)


@pytest.mark.parametrize("scheme", ["systematic", "multinomial"])
def test_other_schemes_equal_python(monkeypatch, scheme: str) -> None:
    """Resampling in one kernel call takes another scheme's ancestors as they are."""
    program = load_grammar(REPO / "grammars" / "vines.lsys")
    mask = disk_mask()
    like = ShapeLikelihood(mask, program.viewport)
    a, b = both(
        monkeypatch, program, like, 30, seed=4, canvas_size=mask.shape, target_mask=mask,
        resample=scheme,
    )  # fmt: skip
    assert a.info["resamples"] > 0
    assert_same(a, b)


def test_circuit_runs_equal_python(monkeypatch) -> None:
    """The circuit likelihood (observe_step's other increment), unguided and guided by the
    bundled circuit guide, on the compiled deriver: the Python deriver's runs."""
    from ngpm_runtime.grow import circuit_target
    from ngpm_runtime.inference.likelihood import CircuitLikelihood

    program = bundled_program()
    target = circuit_target()
    like = CircuitLikelihood(program.viewport)
    guide = bundled_guide(program, "circuit")
    for proposal, n in ((None, 30), (guide, 10)):
        a, b = both(
            monkeypatch,
            program,
            like,
            n,
            proposal,
            seed=3,
            start=target.start_pose(program.viewport),
            canvas_size=target.size,
            trace=TraceRecording.VALUES,
            ess_from_proposal=proposal is not None,
        )
        assert a.steps > 20
        assert_same(a, b)
        # every finished particle carries equation 2 itself, not the potential (a dead
        # one, weight zero, is left as it was)
        vp, size = program.viewport, target.size
        done = [p for p in a.particles if p.status == "done"]
        assert len(done) > n // 2 and all(p.status in ("done", "dead") for p in a.particles)
        for p in done:
            image = rasterize(list(p.primitives), vp, *size)
            boxes = np.array([prim_bbox(q) for q in p.primitives])
            bbox = np.concatenate([boxes[:, :2].min(axis=0), boxes[:, 2:].max(axis=0)])
            want = circuit_loglik(image, bbox, vp)
            assert p.log_likelihood == pytest.approx(want, rel=1e-9, abs=1e-6)


def test_circuit_particles_stopped_at_max_steps_carry_equation_2(monkeypatch) -> None:
    """Particles stopped by max_steps settle too: equation 2 from scratch, not the
    potential, on both derivers."""
    from ngpm_runtime.grow import circuit_target
    from ngpm_runtime.inference.likelihood import CircuitLikelihood

    program, target = bundled_program(), circuit_target()
    vp = program.viewport
    a, b = both(
        monkeypatch,
        program,
        CircuitLikelihood(vp),
        30,
        None,
        seed=1,
        max_steps=20,
        start=target.start_pose(vp),
        canvas_size=target.size,
    )
    assert_same(a, b)
    for p in a.particles:
        assert p.status == "limit"
        image = rasterize(list(p.primitives), vp, *target.size)
        boxes = np.array([prim_bbox(q) for q in p.primitives])
        bbox = np.concatenate([boxes[:, :2].min(axis=0), boxes[:, 2:].max(axis=0)])
        assert p.log_likelihood == pytest.approx(circuit_loglik(image, bbox, vp), rel=1e-9)


def test_guided_vines_runs_equal_python(monkeypatch) -> None:
    """Guided rounds (the bundled guide: kernels.serve_round) on the compiled deriver."""
    program = bundled_program()
    guide = bundled_guide(program)
    for k, target in enumerate(demo_targets()[:2]):
        like = ShapeLikelihood(target.mask, program.viewport)
        for seed in range(2):
            a, b = both(
                monkeypatch,
                program,
                like,
                10,
                guide,
                seed=seed + 10 * k,
                start=target.start_pose(program.viewport),
                canvas_size=target.size,
                target_mask=target.mask,
                trace=TraceRecording.VALUES,
                ess_from_proposal=True,
            )
            assert_same(a, b)


@pytest.mark.parametrize("name", ["lily", "grass", "canopy", "stochastic_plant", "chain"])
def test_shipped_grammars_equal_python(monkeypatch, name: str) -> None:
    program = load_grammar(REPO / "grammars" / f"{name}.lsys")
    mask = disk_mask()
    like = ShapeLikelihood(mask, program.viewport)
    a, b = both(monkeypatch, program, like, 24, seed=7, canvas_size=mask.shape, target_mask=mask)
    assert_same(a, b)


def test_lazy_turtle_arguments_equal_python(monkeypatch) -> None:
    """`turtle arguments: lazy` (sites sampled in generated one-symbol interpretation rules,
    which the kernel runs as productions at any depth): the same feature rows, in runs and
    replays (canopy's runs are compared in test_shipped_grammars_equal_python)."""
    from ngpm_runtime.inference.smc import replay

    program = load_grammar(REPO / "grammars" / "canopy.lsys")  # it says lazy
    assert sum(k.startswith("_late") for k in program.interpretation) == 6
    mask = disk_mask()
    like = ShapeLikelihood(mask, program.viewport)
    opts = dict(seed=5, canvas_size=mask.shape, target_mask=mask, trace=TraceRecording.FULL)
    a, b = both(monkeypatch, program, like, 12, **opts)
    same_traces(a.best.trace, b.best.trace)
    values = [(s, v) for s, _, v in a.best.trace]
    out = []
    for use in (True, False):
        monkeypatch.setattr(smc_module, "USE_COMPILED", use)
        out.append(replay(program, values, canvas_size=mask.shape, target_mask=mask))
    same_traces(out[0].trace, out[1].trace)
    assert out[0].primitives == a.best.primitives


def test_features_equal_python(monkeypatch, tmp_path: Path) -> None:
    program = grammar(tmp_path, FEATURES)
    mask = disk_mask()
    like = ShapeLikelihood(mask, program.viewport)
    kinds = {s.kind for s in program.sites}
    assert kinds == {"normal", "uniform", "bernoulli", "categorical"}
    drawn = set()
    for seed in range(4):
        a, b = both(
            monkeypatch,
            program,
            like,
            30,
            seed=seed,
            canvas_size=mask.shape,
            target_mask=mask,
            trace=TraceRecording.VALUES,
            ess_threshold=0.5,
        )
        assert_same(a, b)
        a, b = both(monkeypatch, program, None, 30, seed=seed)
        assert_same(a, b)
        drawn |= {q[0] for p in a.particles for q in p.primitives}
    assert drawn == {"seg", "disk", "leaf"}
    # a likelihood without a canvas reads the batch's primitives (PrimRows)
    a, b = both(monkeypatch, program, SumXLikelihood(), 20, seed=1)
    assert_same(a, b)


def test_deep_grammar_grows_its_arrays(monkeypatch, tmp_path: Path) -> None:
    program = grammar(tmp_path, DEEP)
    for seed in range(3):
        a, b = both(monkeypatch, program, None, 6, seed=seed, trace=TraceRecording.VALUES)
        assert_same(a, b)
    assert max(len(p.trace) for p in a.particles) > 8


def test_caps_equal_python(monkeypatch, tmp_path: Path) -> None:
    program = grammar(
        tmp_path,
        "derivation length: 30\nmax modules: 200\nAxiom: A\nproduction:\n"
        "A --> A F(uniform(0, 1)) A : 0.5 | F : 0.5\n",
    )
    for seed in range(3):
        a, b = both(monkeypatch, program, None, 8, seed=seed, max_primitives=40, max_steps=60)
        assert_same(a, b)
    assert {p.limit for p in a.particles} - {None}


def test_blank_and_capped_particles_equal_python(monkeypatch, tmp_path: Path) -> None:
    """The shape likelihood's blank image (particles that end having drawn nothing) and the
    primitive cap, observed in one kernel call (observe_step), as the Python deriver does."""
    program = grammar(
        tmp_path,
        "viewport: -4 4 -1 7\nderivation length: 12\nAxiom: A\nproduction:\n"
        "A --> F(uniform(0.5, 1)) + A : 0.8 | halt : 0.2\n",
    )
    mask = disk_mask()
    like = ShapeLikelihood(mask, program.viewport)
    limits, blank = set(), False
    for seed in range(4):
        a, b = both(
            monkeypatch, program, like, 16, seed=seed, canvas_size=mask.shape,
            target_mask=mask, max_primitives=4, ess_threshold=1e-6,
        )  # fmt: skip
        assert_same(a, b)
        limits |= {p.limit for p in a.particles}
        blank = blank or any(not p.primitives for p in a.particles)
    assert limits == {"max primitives", None} and blank


@pytest.mark.parametrize(
    "rule, error",
    [
        ("A(x) --> F(sqrt(x - 2)) A(x - 1)", "math domain error"),
        ("A(x) --> F(1 / x) A(x - 1)", "ZeroDivisionError"),
        ("A(x) --> F(gauss(0, x - 2)) A(x - 1)", "standard deviation must be >= 0"),
        ("A(x) --> F(pow(x - 3, 0.5)) A(x - 1)", "math domain error"),
        ("A(x) --> F(exp(x * 300)) A(x - 1)", "math range error"),
    ],
)
def test_errors_are_the_python_derivers(monkeypatch, tmp_path: Path, rule: str, error: str):
    program = grammar(tmp_path, f"derivation length: 9\nAxiom: A(4)\nproduction:\n{rule}\n")
    messages = []
    monkeypatch.setattr(smc_module, "COMPILE_FROM", 1)
    for use in (True, False):
        monkeypatch.setattr(smc_module, "USE_COMPILED", use)
        with pytest.raises(ProgramError) as err:
            smc(program, None, 3, options=SMCOptions(seed=0))
        messages.append(str(err.value))
    assert messages[0] == messages[1]
    assert error in messages[0]


def test_what_the_kernel_does_not_run(tmp_path: Path) -> None:
    """Interpretation rules (but those of one turtle symbol), polygons and 3D grammars stay
    with the Python deriver."""
    interp = grammar(
        tmp_path,
        "Axiom: A\nproduction:\nA --> L F\ninterpretation:\nL --> [ ~l(1, 1) ]\n",
        "i.lsys",
    )
    poly = grammar(tmp_path, "Axiom: A\nproduction:\nA --> { . f + . f + . }\n", "p.lsys")
    three = load_grammar(REPO / "grammars" / "tree3d.lsys")
    for program in (interp, poly, three):
        assert compiled_deriver(program) is None
        res = smc(program, None, 2, options=SMCOptions(seed=0))
        assert res.info.get("deriver") is None


def test_small_runs_compile_nothing(monkeypatch, tmp_path: Path) -> None:
    """A run of fewer than COMPILE_FROM particles uses the compiled deriver only once it is
    compiled (a larger run compiled it): a quick sample pays no compile time."""
    monkeypatch.setenv("NGPM_KERNEL_CACHE", str(tmp_path / "kernels"))  # nothing on disk
    program = grammar(
        tmp_path, "derivation length: 5\nAxiom: A\nproduction:\nA --> F(gauss(1, 0.1)) A\n"
    )
    small = smc_module.COMPILE_FROM - 1
    assert smc(program, None, small).info.get("deriver") is None
    assert smc(program, None, smc_module.COMPILE_FROM).info.get("deriver") == "compiled"
    assert smc(program, None, small).info.get("deriver") == "compiled"


class Steps(smc_module.SMCObserver):
    """Records what a step observer sees."""

    def __init__(self) -> None:
        self.seen: list = []

    def step_done(self, state) -> None:
        self.seen.append((state.steps, list(state.drawn), list(state.prims)))

    def resampled(self, ancestors) -> None:
        self.seen.append(("resampled", ancestors.tolist()))


def test_step_observers_see_the_same(monkeypatch) -> None:
    """A step observer (progress bars, the web page) keeps the compiled deriver and sees
    what it sees with the Python one; an observer of site draws gets the Python one."""
    program = load_grammar(REPO / "grammars" / "vines.lsys")
    mask = disk_mask()
    like = ShapeLikelihood(mask, program.viewport)
    monkeypatch.setattr(smc_module, "COMPILE_FROM", 1)
    seen = []
    for use in (True, False):
        monkeypatch.setattr(smc_module, "USE_COMPILED", use)
        obs = Steps()
        opts = SMCOptions(seed=2, canvas_size=mask.shape, target_mask=mask)
        res = smc(program, like, 12, options=opts, observers=[obs])
        assert res.info.get("deriver") == ("compiled" if use else None)
        seen.append(obs.seen)
    assert seen[0] == seen[1]

    class Draws(smc_module.SMCObserver):
        def site_drawn(self, site, idx, values) -> None:
            pass

    res = smc(program, like, 12, options=opts, observers=[Draws()])
    assert res.info.get("deriver") is None


def test_no_cache_folder_means_the_python_deriver(monkeypatch, tmp_path: Path) -> None:
    """Where no kernel module can be written (or loaded), runs use the Python deriver."""
    from ngpm_runtime.geometry import compiled

    def no_folder(name: str, text: str) -> Path:
        raise OSError("read-only")

    monkeypatch.setattr(compiled, "_write", no_folder)
    program = grammar(
        tmp_path, "derivation length: 4\nAxiom: A\nproduction:\nA --> F(flip(0.5)) A\n"
    )
    assert compiled_deriver(program) is None
    res = smc(program, None, smc_module.COMPILE_FROM, options=SMCOptions(seed=1))
    assert res.info.get("deriver") is None and res.particles


def same_traces(a, b) -> None:
    assert len(a) == len(b)
    for (s, f, v), (t, g, w) in zip(a, b, strict=True):
        assert (s, v) == (t, w)
        assert f.dtype == g.dtype and np.array_equal(f, g)


def test_feature_traces_equal_python(monkeypatch) -> None:
    """Feature traces (TraceRecording.FULL: the prior's runs, and `replay`, which trace jobs
    run on their best particle) on the compiled deriver: the same rows, bit for bit."""
    from ngpm_runtime.inference.smc import replay

    program = load_grammar(REPO / "grammars" / "vines.lsys")
    mask = disk_mask()
    like = ShapeLikelihood(mask, program.viewport)
    monkeypatch.setattr(smc_module, "COMPILE_FROM", 1)
    out = []
    for use in (True, False):
        monkeypatch.setattr(smc_module, "USE_COMPILED", use)
        opts = SMCOptions(
            seed=4, canvas_size=mask.shape, target_mask=mask, trace=TraceRecording.FULL
        )
        out.append(smc(program, like, 20, options=opts))
    a, b = out
    assert a.info.get("deriver") == "compiled" and b.info.get("deriver") is None
    for p, q in zip(a.particles, b.particles, strict=True):
        assert p.primitives == q.primitives and p.log_weight == q.log_weight
        same_traces(p.trace, q.trace)
    values = [(s, v) for s, _, v in a.best.trace]
    replays = []
    for use in (True, False):
        monkeypatch.setattr(smc_module, "USE_COMPILED", use)
        replays.append(replay(program, values, canvas_size=mask.shape, target_mask=mask))
    assert replays[0].primitives == replays[1].primitives == a.best.primitives
    same_traces(replays[0].trace, replays[1].trace)
    same_traces(replays[0].trace, a.best.trace)


@pytest.mark.parametrize("text", [FEATURES, DEEP], ids=["features", "deep"])
def test_replay_served_in_kernel(monkeypatch, tmp_path, text) -> None:
    """A replay's values are served by the kernel (ReplayProposal.propose runs only where
    it cannot: a production's values past the first 8 columns): the same primitives,
    feature rows, log prior and weight as the Python deriver's replay, bit for bit."""
    from ngpm_runtime.inference.proposals import ReplayProposal
    from ngpm_runtime.inference.smc import replay

    program = grammar(tmp_path, text)
    mask = disk_mask()
    monkeypatch.setattr(smc_module, "COMPILE_FROM", 1)
    src = smc(program, None, 4, options=SMCOptions(seed=3, trace=TraceRecording.VALUES))
    values = [(s, v) for s, _, v in max(src.particles, key=lambda p: len(p.trace)).trace]
    assert len(values) > 10
    calls = []
    propose = ReplayProposal.propose

    def counted(self, *args):
        calls.append(1)
        return propose(self, *args)

    monkeypatch.setattr(ReplayProposal, "propose", counted)
    out = []
    for use in (True, False):
        monkeypatch.setattr(smc_module, "USE_COMPILED", use)
        calls.clear()
        out.append(replay(program, values, canvas_size=mask.shape, target_mask=mask))
        if use:
            assert len(calls) < len(values) // 2
        else:
            assert len(calls) == len(values)
    a, b = out
    assert a.primitives == b.primitives
    assert (a.log_prior, a.log_weight) == (b.log_prior, b.log_weight)
    same_traces(a.trace, b.trace)


@pytest.mark.parametrize("cut", ["short", "wrong site", "long"])
def test_replay_errors_equal_python(monkeypatch, tmp_path, cut) -> None:
    """A replay whose values run out, name another site or are left over: the same
    ProgramError on both derivers."""
    from ngpm_runtime.inference.smc import replay

    program = grammar(tmp_path, FEATURES)
    monkeypatch.setattr(smc_module, "COMPILE_FROM", 1)
    src = smc(program, None, 1, options=SMCOptions(seed=2, trace=TraceRecording.VALUES))
    values = [(s, v) for s, _, v in src.particles[0].trace]
    if cut == "short":
        values = values[: len(values) // 2]
    elif cut == "wrong site":
        s, v = values[3]
        values[3] = ((s + 1) % len(program.sites), v)
    else:
        values = values + [values[-1]]
    errors = []
    for use in (True, False):
        monkeypatch.setattr(smc_module, "USE_COMPILED", use)
        with pytest.raises(ProgramError) as err:
            replay(program, values, canvas_size=(32, 32), target_mask=disk_mask())
        errors.append(str(err.value))
    assert errors[0] == errors[1]


def test_replay_kernel_error_reruns_from_start(monkeypatch, tmp_path) -> None:
    """A replay the kernel cannot finish (a math domain error) runs again on the Python
    deriver from its first value: the Python deriver's located error, as without it."""
    from ngpm_runtime.inference.smc import replay

    program = grammar(
        tmp_path,
        "viewport: -9 9 -9 9\nderivation length: 6\nAxiom: A\nproduction:\n"
        "A --> F(sqrt(gauss(0, 1))) A\n",
    )
    values = [(0, 1.0), (0, 1.0), (0, -1.0)]
    monkeypatch.setattr(smc_module, "COMPILE_FROM", 1)
    assert compiled_deriver(program) is not None
    starts = []  # where each run's replay starts
    init = smc_module._Run.__init__

    def recorded(self, *args):
        starts.append((type(self).__name__, args[3].pos))
        init(self, *args)

    monkeypatch.setattr(smc_module._Run, "__init__", recorded)
    errors = []
    for use in (True, False):
        monkeypatch.setattr(smc_module, "USE_COMPILED", use)
        with pytest.raises(ProgramError) as err:
            replay(program, values, canvas_size=(32, 32), target_mask=disk_mask())
        errors.append(str(err.value))
    assert errors[0] == errors[1] and "math domain error" in errors[0]
    assert starts == [("CompiledRun", 0), ("_Run", 0), ("_Run", 0)]
