"""Derivation semantics: turtle, expansion order, depth, interpretation, cut, halt, caps,
replay and error reporting."""

import math

import numpy as np
import pytest
from fixtures.tiny_programs import make_program
from ngpm_runtime.errors import ProgramError
from ngpm_runtime.geometry.derive import DONE, DRAWN, LIMIT, NEED, Deriver
from ngpm_runtime.geometry.turtle import prim_bbox
from ngpm_runtime.inference.smc import SMCOptions, forward, smc
from ngpm_runtime.program import Site, load_program
from repo_paths import REPO, VINES_SAMPLER

VINES = VINES_SAMPLER


def prims_of(program, **kw):
    return forward(program, **kw).primitives


def approx(a, b):
    assert len(a) == len(b), (a, b)
    for p, q in zip(a, b, strict=True):
        assert p[0] == q[0]
        if p[0] == "poly":
            np.testing.assert_allclose(np.array(p[1]), np.array(q[1]), atol=1e-12)
        else:
            np.testing.assert_allclose(p[1:], q[1:], atol=1e-12)


def test_turtle_symbols() -> None:
    prog = make_program(
        {},
        axiom=[
            ("F", 2.0),
            ("+", 90.0),
            ("!", 0.5),
            ("F", 1.0),
            ("-", 45.0),
            ("|",),
            ("f", 1.0),
            ("[",),
            ("+", 90.0),
            ("F", 1.0),
            ("]",),
            ("~l", 2.0, 0.4),
            ("@O", 0.3),
            ("{",),
            (".",),
            ("f", 1.0),
            (".",),
            ("+", 90.0),
            ("f", 1.0),
            (".",),
            ("}",),
            ("Q", 7.0),
        ],
    )
    s = math.sqrt(0.5)
    # after F(2) +90 F(1): at (2, 1), heading 90; -45 | -> heading 225; f(1) -> (2-s, 1-s)
    x, y = 2 - s, 1 - s
    want = [
        ("seg", 0.0, 0.0, 2.0, 0.0, 1.0),
        ("seg", 2.0, 0.0, 2.0, 1.0, 0.5),
        ("seg", x, y, x + math.cos(math.radians(315)), y + math.sin(math.radians(315)), 0.5),
        ("leaf", x, y, 225.0, 2.0, 0.4),
        ("disk", x, y, 0.3),
        ("poly", ((x, y), (x - s, y - s), (x - s + s, y - s - s))),
    ]
    approx(prims_of(prog), want)


def test_default_turn_angle_and_start_argument() -> None:
    prog = make_program({}, axiom=[("+",), ("F", 1.0), ("-",), ("-",), ("F", 1.0)], angle=60.0)
    got = prims_of(prog, start=(1.0, 2.0, 30.0))
    approx(
        got,
        [
            ("seg", 1.0, 2.0, 1.0, 3.0, 1.0),
            (
                "seg",
                1.0,
                3.0,
                1.0 + math.cos(math.radians(-30)),
                3.0 + math.sin(math.radians(-30)),
                1.0,
            ),
        ],
    )


def test_program_start_used_by_default() -> None:
    prog = make_program({}, axiom=[("F", 1.0)], start=(3.0, -1.0, 90.0))
    approx(prims_of(prog), [("seg", 3.0, -1.0, 3.0, 0.0, 1.0)])


def test_expansion_is_leftmost_depth_first_and_depth_limited() -> None:
    # A(i) --> F(i) A(i + 1): axiom depth 0, so derivation_length 3 expands A three times
    prog = make_program(
        {"A": lambda ctx, i: [("F", i), ("A", i + 1.0)]}, axiom=[("A", 1.0)], derivation_length=3
    )
    got = prims_of(prog)
    assert [p[3] for p in got] == [1.0, 3.0, 6.0]


def test_successor_order() -> None:
    # A --> B C, B --> F(1), C --> F(2): B's successor is drawn before C's
    prog = make_program(
        {
            "A": lambda ctx: [("B",), ("C",)],
            "B": lambda ctx: [("F", 1.0)],
            "C": lambda ctx: [("F", 2.0)],
        }
    )
    assert [p[3] for p in prims_of(prog)] == [1.0, 3.0]


def test_production_returning_none_leaves_module_for_the_turtle() -> None:
    prog = make_program(
        {"F": lambda ctx, n: None if n < 2 else [("F", n / 2), ("F", n / 2)]}, axiom=[("F", 4.0)]
    )
    assert [p[3] - p[1] for p in prims_of(prog)] == [1.0, 1.0, 1.0, 1.0]


def test_empty_successor_deletes() -> None:
    prog = make_program({"A": lambda ctx: []}, axiom=[("A",), ("F", 1.0)])
    assert len(prims_of(prog)) == 1


def test_cut_discards_rest_of_branch_only() -> None:
    prog = make_program(
        {},
        axiom=[
            ("[",),
            ("F", 1.0),
            ("[",),
            ("F", 5.0),
            ("]",),
            ("%",),
            ("F", 7.0),
            ("[",),
            ("F", 9.0),
            ("]",),
            ("]",),
            ("F", 2.0),
            ("%",),
            ("F", 3.0),
        ],
    )
    got = prims_of(prog)
    assert [p[3] - p[1] for p in got] == [1.0, 5.0, 2.0]
    assert got[2][1] == 0.0  # the branch's ] restored the pose


def test_cut_reaches_across_successors() -> None:
    """A cut inside a successor discards what is left of it and of the successors that
    enclose it (brackets inside them included) up to the `]` of the branch."""
    prog = make_program(
        {
            "A": lambda ctx: [("F", 1.0), ("B",), ("[",), ("F", 8.0), ("]",), ("F", 6.0)],
            "B": lambda ctx: [("%",), ("F", 9.0)],
        },
        axiom=[("[",), ("A",), ("F", 7.0), ("]",), ("F", 2.0), ("B",), ("F", 4.0)],
    )
    got = prims_of(prog)
    assert [p[3] - p[1] for p in got] == [1.0, 2.0]


def test_halt_discards_everything() -> None:
    prog = make_program(
        {"A": lambda ctx: [("F", 1.0), ("halt",), ("F", 2.0)]},
        axiom=[("[",), ("A",), ("]",), ("F", 3.0)],
    )
    assert len(prims_of(prog)) == 1


def test_interpretation_rules() -> None:
    # L is interpreted as a disk; interpretation output is interpreted recursively, never
    # expanded by productions (M has a production that would draw a segment)
    prog = make_program(
        {"M": lambda ctx: [("F", 9.0)]},
        axiom=[("L", 0.5), ("F", 1.0)],
        interpretation={"L": lambda ctx, r: [("N", r)], "N": lambda ctx, r: [("@O", r), ("M",)]},
    )
    approx(prims_of(prog), [("disk", 0.0, 0.0, 0.5), ("seg", 0.0, 0.0, 1.0, 0.0, 1.0)])


def test_interpretation_rule_with_random_site() -> None:
    sites = [Site(index=0, id="interp:L/0/normal0", kind="normal", module="L")]
    prog = make_program(
        {},
        axiom=[("L",)],
        sites=sites,
        interpretation={"L": lambda ctx: [("F", ctx.normal(0, 5.0, 0.0))]},
    )
    approx(prims_of(prog), [("seg", 0.0, 0.0, 5.0, 0.0, 1.0)])


def test_module_with_production_past_derivation_length_gets_interpreted() -> None:
    prog = make_program(
        {"A": lambda ctx: [("A",), ("A",)]},
        axiom=[("A",)],
        derivation_length=2,
        interpretation={"A": lambda ctx: [("F", 1.0)]},
    )
    assert len(prims_of(prog)) == 4


def test_runaway_interpretation_recursion_raises() -> None:
    prog = make_program({}, axiom=[("A",)], interpretation={"A": lambda ctx: [("A",)]})
    with pytest.raises(ProgramError, match="64"):
        forward(prog)


def test_errors_in_generated_code_name_module_and_line() -> None:
    def produce_a(ctx, w):
        return [("F", 1.0 / w)]

    prog = make_program(
        {"A": produce_a},
        axiom=[("A", 0.0)],
        source="g/tiny.lsys",
        locations={"production A": (7, 1)},
    )
    with pytest.raises(ProgramError, match=r"tiny\.lsys:7: production A.*ZeroDivisionError"):
        forward(prog)

    def produce_b(ctx):
        return [("F", math.sqrt(-1.0))]

    prog = make_program(
        {"B": produce_b}, axiom=[("B",)], source="tiny.lsys", locations={"production B": (9, 1)}
    )
    with pytest.raises(ProgramError, match=r"tiny\.lsys:9: production B.*math domain"):
        forward(prog)


def test_error_in_axiom_names_the_axiom() -> None:
    def axiom(ctx):
        return [("F", 1 / 0)]

    with pytest.raises(ProgramError, match=r"^tiny\.lsys:3: axiom: ZeroDivisionError"):
        forward(make_program({}, axiom=axiom, source="tiny.lsys", locations={"axiom": (3, 8)}))


def test_error_locations_come_from_the_locations_table_not_docstrings() -> None:
    """Issue #21: the deriver read rule lines back out of docstrings by regex; the generated
    module now hands them over as its LOCATIONS table."""

    def produce_a(ctx):
        """A --> F(1 / 0)   (other.lsys:99)"""
        return [("F", 1 / 0)]

    prog = make_program(
        {"A": produce_a}, source="grammars/tiny.lsys", locations={"production A": (7, 3)}
    )
    with pytest.raises(ProgramError, match=r"^tiny\.lsys:7: production A: ZeroDivision"):
        forward(prog)
    with pytest.raises(ProgramError, match=r"^production A: ZeroDivision"):
        forward(make_program({"A": produce_a}, source="grammars/tiny.lsys"))


def test_bad_successor_and_turtle_arguments_raise() -> None:
    with pytest.raises(ProgramError, match="not a module tuple"):
        forward(make_program({"A": lambda ctx: ["F"]}))
    with pytest.raises(ProgramError, match="turtle"):
        forward(make_program({}, axiom=[("F", "x")]))
    with pytest.raises(ProgramError, match="turtle"):
        forward(make_program({}, axiom=[("~l", "x", 1.0)]))
    with pytest.raises(ProgramError, match="turtle"):
        forward(make_program({}, axiom=[("@O", None)]))
    with pytest.raises(ProgramError, match="without a matching"):
        forward(make_program({}, axiom=[("]",)]))


def test_impure_production_is_detected() -> None:
    sites = [Site(index=0, id="a", kind="normal"), Site(index=1, id="b", kind="normal")]
    calls = []

    def impure(ctx):
        calls.append(1)
        return [("F", ctx.normal(len(calls) % 2, 0.0, 1.0))]

    with pytest.raises(ProgramError, match="not pure"):
        forward(make_program({"A": impure}, sites=sites))


def test_replay_asks_sites_one_at_a_time() -> None:
    sites = [Site(index=0, id="a", kind="normal"), Site(index=1, id="b", kind="normal")]
    prog = make_program(
        {"A": lambda ctx: [("F", ctx.normal(0, 0, 1)), ("F", ctx.normal(1, 5, 2))]}, sites=sites
    )
    d = Deriver(prog)
    p = d.start((0.0, 0.0, 0.0, 1.0))
    assert d.advance(p) == NEED and p.need == (0, (0, 1))
    p.values += (2.0,)
    p.sites += (0,)
    assert d.advance(p) == NEED and p.need == (1, (5, 2))
    p.values += (3.0,)
    p.sites += (1,)
    assert d.advance(p) == DRAWN and p.last[3] == 2.0
    q = p.copy()
    assert d.advance(p) == DRAWN and p.last[3] == 5.0
    assert d.advance(p) == DONE
    # the copy is independent of the original
    assert d.advance(q) == DRAWN and q.last[3] == 5.0 and q.n_prims == 2


def test_a_stop_inside_a_successor_keeps_its_rest_on_the_stack() -> None:
    """The deriver reads a successor in place; where a particle stops inside one (a drawn
    primitive, a request), the rest of it is on its stack as (module, depth, level) nodes,
    the waiting module on top (SMC reads its parameters and depth for the features)."""
    sites = [Site(index=0, id="B/0/normal0", kind="normal", module="B", arity=1)]
    prog = make_program(
        {
            "A": lambda ctx: [("+", 10.0), ("F", 1.0), ("B", 2.0), ("F", 3.0)],
            "B": lambda ctx, w: [("F", ctx.normal(0, w, 1.0))],
        }
    )
    prog.sites.extend(sites)
    d = Deriver(prog)
    p = d.start((0.0, 0.0, 0.0, 1.0))
    assert d.advance(p) == DRAWN and p.last[0] == "seg" and p.n_prims == 1
    # the look-ahead stopped at B's request: B on top at depth 1, then F(3)
    assert p.need == (0, (2.0, 1.0))
    assert p.stack[:3] == (("B", 2.0), 1, 0)
    assert p.stack[3][:3] == (("F", 3.0), 1, 0) and p.stack[3][3] is None
    p.values += (4.0,)
    p.sites += (0,)
    assert d.advance(p) == DRAWN and p.n_prims == 2
    assert p.stack[:3] == (("F", 3.0), 1, 0)  # a drawing symbol after a drawing: stop
    assert d.advance(p) == DRAWN and p.stack is None and p.n_prims == 3


def test_turtle_tables_cover_the_turtle_symbols() -> None:
    from ngpm_runtime.geometry.turtle import TURTLE_OPS, TURTLE_SYMBOLS, interpret
    from ngpm_runtime.geometry.turtle3d import TURTLE3D_OPS, TURTLE3D_SYMBOLS, interpret3d

    assert frozenset(TURTLE_OPS) == TURTLE_SYMBOLS
    assert frozenset(TURTLE3D_OPS) == TURTLE3D_SYMBOLS
    turtle = (1.0, 2.0, 30.0, 0.5)
    assert interpret(("Q", 1.0), turtle, None, None, 90.0) == (turtle, None, None, None)
    assert interpret(("+",), turtle, None, None, 90.0)[0] == (1.0, 2.0, 120.0, 0.5)
    t3 = (0.0,) * 14 + (None,)
    assert interpret3d(("Q",), t3, None, None, 90.0) == (t3, None, None, None)


def test_axiom_may_draw_random_values() -> None:
    sites = [Site(index=0, id="axiom/normal0", kind="normal")]
    prog = make_program({}, axiom=lambda ctx: [("F", ctx.normal(0, 2.0, 0.0))], sites=sites)
    approx(prims_of(prog), [("seg", 0.0, 0.0, 2.0, 0.0, 1.0)])


def test_primitive_cap_gives_limit_status() -> None:
    prog = make_program({"A": lambda ctx: [("F", 1.0), ("A",)]}, max_primitives=5)
    f = forward(prog)
    assert f.status == "limit" and len(f.primitives) == 5
    r = smc(prog, None, 3, options=SMCOptions(max_primitives=2))
    assert all(p.status == "limit" and len(p.primitives) == 2 for p in r.particles)
    r = smc(prog, None, 3, options=SMCOptions(max_steps=4))
    assert all(p.status == "limit" and len(p.primitives) == 4 for p in r.particles)
    assert r.info["status"] == {"done": 0, "limit": 3, "dead": 0}
    assert r.info["limits"] == {"max steps": 3} and f.limit == "max primitives"


def test_work_cap_without_drawing_gives_limit() -> None:
    prog = make_program({"A": lambda ctx: [("A",), ("A",)]}, derivation_length=40)
    d = Deriver(prog, max_modules=10_000)
    p = d.start((0.0, 0.0, 0.0, 1.0))
    assert d.advance(p) == LIMIT
    r = smc(prog, None, 2, options=SMCOptions(max_modules=500))
    assert [(q.status, q.limit) for q in r.particles] == [("limit", "max modules")] * 2
    assert r.info["limits"] == {"max modules": 2}


def test_prim_bbox() -> None:
    # (xmin, ymin, xmax, ymax), as raster.DrawBatch.bbox
    assert prim_bbox(("seg", 0, 0, 2, 1, 0.5)) == (-0.25, -0.25, 2.25, 1.25)
    assert prim_bbox(("disk", 1, 2, 0.5)) == (0.5, 1.5, 1.5, 2.5)
    np.testing.assert_allclose(prim_bbox(("leaf", 0, 0, 90.0, 2.0, 1.0)), (-0.5, 0, 0.5, 2))
    assert prim_bbox(("poly", ((0, 0), (2, 0), (1, 3)))) == (0, 0, 2, 3)


def test_vines_fixture_forward() -> None:
    prog = load_program(VINES)
    lengths = []
    for seed in range(30):
        f = forward(prog, seed=seed)
        assert f.status == "done"
        first = f.primitives[0]
        assert first[0] == "seg" and first[1:3] == (0.0, 0.0) and first[5] == 0.75
        assert all(p[0] in ("seg", "leaf", "disk") for p in f.primitives)
        assert np.isfinite(f.log_prior) and f.log_likelihood == 0.0
        lengths.append(len(f.primitives))
    assert max(lengths) > 3
    assert forward(prog, seed=7).primitives == forward(prog, seed=7).primitives


def test_compiled_vines_matches_hand_written_fixture() -> None:
    from ngpm_compiler.language.compile import compile_grammar

    compiled = compile_grammar(str(REPO / "grammars" / "vines.lsys"))
    prog = compiled.program()
    fixture = load_program(VINES)
    assert [s.id for s in prog.sites] == [s.id for s in fixture.sites]
    for seed in range(20):
        a = forward(prog, seed=seed, start=(0.0, -16.0, 90.0))
        b = forward(fixture, seed=seed, start=(0.0, -16.0, 90.0))
        assert a.primitives == b.primitives and a.log_prior == b.log_prior


def test_one_bbox_scalar_and_batched_agree() -> None:
    from ngpm_runtime.geometry.turtle import prim_bboxes

    rng = np.random.default_rng(0)
    prims = [("seg", *rng.normal(size=4), abs(rng.normal())) for _ in range(50)]
    prims += [("disk", *rng.normal(size=2), rng.normal()) for _ in range(50)]
    prims += [
        ("leaf", *rng.normal(size=2), rng.uniform(-720, 720), *rng.normal(size=2))
        for _ in range(200)
    ]
    prims += [("poly", tuple(map(tuple, rng.normal(size=(5, 2))))) for _ in range(20)]
    for p in prims:
        assert prim_bboxes(p[0], [p])[0][0].tolist() == list(prim_bbox(p))


# ---- issue #27: invalid run-time prior arguments, runaway work ----------------------------

BAD_PRIORS = [
    ("F(gauss(0, -x))", "gauss(0, -x) (line 4:12): the standard deviation must be >= 0, got -1"),
    ("F(uniform(x, 0))", "uniform(x, 0) (line 4:12): needs a <= b, got a = 1, b = 0"),
    ("F(flip(2 * x))", "flip(2 * x) (line 4:12): the probability must be in [0, 1], got 2"),
    ("F(choice(x, -x))", "choice(x, -x) (line 4:12): weights must be >= 0 with a positive sum"),
]


@pytest.mark.parametrize("successor, words", BAD_PRIORS)
def test_invalid_prior_arguments_at_run_time_are_errors(successor: str, words: str) -> None:
    """Finding 5: gauss(0, -1) used |sd|, uniform(1, 0) swapped, flip(2) clipped, silently.
    The deriver checks the arguments of every request before any proposal sees them, so
    the prior, SMC, replay and guided paths all stop with the same error."""
    from ngpm_runtime.inference.smc import SMCOptions, replay

    from ngpm_compiler.language.compile import compile_grammar

    prog = compile_grammar(
        f"viewport: -5 5 -5 5\nderivation length: 1\nAxiom: A(1)\nA(x) --> {successor}\n",
        filename="bad.lsys",
    ).program()
    for run in (
        lambda: forward(prog),
        lambda: smc(prog, None, 4, options=SMCOptions(seed=1)),
        lambda: replay(prog, [(0, 0.0)]),
    ):
        with pytest.raises(ProgramError) as info:
            run()
        assert str(info.value).startswith(f"bad.lsys:4: production A(1): {words}")


def test_degenerate_priors_at_run_time_are_point_masses() -> None:
    from ngpm_compiler.language.compile import compile_grammar

    prog = compile_grammar(
        "derivation length: 1\nAxiom: A(0)\nA(x) --> F(gauss(1, x)) F(uniform(x + 2, 2))\n"
    ).program()
    lengths = [math.hypot(p[3] - p[1], p[4] - p[2]) for p in forward(prog).primitives]
    assert lengths == pytest.approx([1.0, 2.0], abs=1e-12)


def test_a_request_for_an_unknown_site_is_an_error() -> None:
    prog = make_program({"A": lambda ctx: [("F", ctx.normal(3, 0.0, 1.0))]})
    with pytest.raises(ProgramError, match="asks for site 3, not one of the program's 0 sites"):
        forward(prog)


def test_one_samples_work_has_a_ceiling(monkeypatch) -> None:
    """Finding 3: whatever the caps, one sample's whole derivation stops at MAX_WORK modules
    (or MAX_PRIMITIVES primitives) with an error naming the cause."""
    from ngpm_runtime.geometry import derive

    def waste(ctx, n):  # 50 modules of work per primitive, for ever
        return [("B", n - 1.0)] if n > 0 else [("F", 0.01), ("B", 50.0)]

    prog = make_program(
        {"B": waste}, axiom=[("B", 50.0)], max_primitives=10**18, source="grammars/waste.lsys"
    )
    monkeypatch.setattr(derive, "MAX_WORK", 5000)
    with pytest.raises(
        ProgramError,
        match=r"^waste\.lsys: one sample expanded or interpreted "
        r"more than 5000 modules",
    ):
        forward(prog)
    monkeypatch.setattr(derive, "MAX_WORK", 10**9)
    monkeypatch.setattr(derive, "MAX_PRIMITIVES", 30)
    with pytest.raises(ProgramError, match="one sample drew more than 30 primitives"):
        smc(prog, None, 3, options=SMCOptions(seed=0))


def test_advance_all_equals_advance_one_by_one() -> None:
    """A round's particles advanced in one call end as each advanced alone: the same
    outcomes, requests, primitives and stacks (vines, values fed in by hand)."""
    d = Deriver(load_program(VINES))
    rng = np.random.default_rng(3)
    together = [d.start((0.0, 0.0, 90.0, 1.0)) for _ in range(6)]
    alone = [p.copy() for p in together]
    for _ in range(40):
        codes = d.advance_all(together)
        assert codes == [d.advance(p) for p in alone]
        for p, q in zip(together, alone, strict=True):
            assert (p.need, p.stack, p.turtle, p.n_prims, p.work) == (
                q.need,
                q.stack,
                q.turtle,
                q.n_prims,
                q.work,
            )
            if p.need is not None:  # waiting (NEED, or DRAWN with a look-ahead request)
                site, v = p.need[0], float(rng.integers(0, 2))  # 0 or 1: a choice too
                for r in (p, q):
                    r.values += (v,)
                    r.sites += (site,)
                    r.need = None
        live = [k for k, c in enumerate(codes) if c in (DRAWN, NEED)]
        together = [together[k] for k in live]
        alone = [alone[k] for k in live]
        if not together:
            break
    assert d.advance_all([]) == []
