"""'turtle arguments: lazy': random turtle arguments sampled where the turtle reaches them.

The samples' distribution must not change (exact enumeration of a tiny grammar, SMC on it),
each site keeps its id and number, and a site after a drawing sees the turtle past it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from fixtures.exact import check, exact, pooled, tv
from fixtures.tiny_programs import TINY_LSYS, SumXLikelihood
from ngpm_runtime.geometry.cons import cons_to_list
from ngpm_runtime.geometry.derive import DRAWN, NEED, Deriver
from ngpm_runtime.inference.proposals import FixedProposal

from ngpm_compiler.language.compile import compile_grammar
from ngpm_compiler.language.errors import GrammarError

TINY = TINY_LSYS.replace("Axiom:", "{lazy}\nAxiom:")  # test_exact.py's tiny grammar


def program(text: str, lazy: str = "turtle arguments: lazy"):
    return compile_grammar(text.replace("{lazy}", lazy), filename="t.lsys").program()


def test_sites_keep_their_ids_and_numbers() -> None:
    eager, lazy = program(TINY, ""), program(TINY)
    assert [(s.id, s.kind, s.module, s.arity) for s in lazy.sites] == [
        (s.id, s.kind, s.module, s.arity) for s in eager.sites
    ]
    # the + and the F after F(1) are deferred; @O and the interpretation rule's @O are first
    late = sorted(k for k in lazy.interpretation if k.startswith("_late"))
    assert late == ["_late1", "_late2"]
    assert set(eager.interpretation) == {"L"}


# random turns in the axiom and in an interpretation rule, after drawings
INTERP = """
derivation length: 3
start: 0 0 0
{lazy}
Axiom: F(0.5) +(90 * flip(0.5)) A
production:
A --> F(1) L [ -(45 * categorical(1, 1, 2)) F(1 + flip(0.5)) ] A : 0.5 | L : 0.5
interpretation:
L --> F(0.5) +(30 * flip(0.3)) F(0.25)
"""


@pytest.mark.parametrize(("text", "late"), [(TINY, 2), (INTERP, 4)])
def test_the_distribution_of_samples_is_the_same(text: str, late: int) -> None:
    eager, lazy = program(text, ""), program(text)
    assert sum(k.startswith("_late") for k in lazy.interpretation) == late
    like = SumXLikelihood(goal=3.0, scale=1.5)
    want_post, want_log_z = exact(eager, like)
    got_post, got_log_z = exact(lazy, like)
    assert len(want_post) > 10
    assert tv(got_post, want_post) < 1e-12
    assert math.isclose(got_log_z, want_log_z, abs_tol=1e-12)


@pytest.mark.parametrize(
    ("scheme", "ess", "prop"), [("residual", None, None), ("systematic", 0.5, "q")]
)
def test_smc_on_a_lazy_grammar_is_exact(scheme, ess, prop) -> None:
    prog = program(TINY)
    q = FixedProposal({0: [0.3, 0.7], 1: [0.2, 0.2, 0.6], 2: [0.7], 3: [0.4, 0.6], 4: [0.9]})
    like = SumXLikelihood(goal=3.0, scale=1.5)
    want_post, want_log_z = exact(prog, like)
    post, log_z = pooled(prog, like, q if prop else None, scheme, ess, seed=30)
    assert check(post, log_z, want_post, want_log_z, 0.08), (tv(post, want_post), log_z, want_log_z)


def first_request(prog, site: int):
    """The primitives drawn and the turtle when a derivation first asks for `site` (every
    earlier request answered with 0)."""
    d = Deriver(prog)
    p = d.start((*prog.start, 1.0))
    while True:
        code = d.advance(p)
        if code == NEED:
            s, _ = p.need
            if s == site:
                return list(cons_to_list(p.prims)), p.turtle
            p.values += (0.0,)
            p.sites += (s,)
            p.need = None
        else:
            assert code == DRAWN, "the derivation ended before the site"


BRANCH = """
start: 0 0 90
{lazy}
Axiom: A
production:
A --> F(2) [ +(gauss(30, 5)) F(1) ] [ -(gauss(30, 5)) F(1) ]
endlsystem
"""


def test_a_late_site_sees_the_turtle_past_the_drawing() -> None:
    eager, lazy = program(BRANCH, ""), program(BRANCH)
    # eager: both angles are drawn when A expands, before anything is drawn
    prims, turtle = first_request(eager, 1)
    assert prims == [] and turtle[:2] == pytest.approx((0.0, 0.0))
    # lazy: the second angle is drawn at the fork, after the trunk and the first branch
    prims, turtle = first_request(lazy, 1)
    assert len(prims) == 2 and turtle[:2] == pytest.approx((0.0, 2.0))
    np.testing.assert_allclose(turtle[2] % 360, 90.0)


def test_what_stays_eager() -> None:
    text = """
derivation length: 2
{lazy}
Axiom: +(gauss(0, 1)) A(1)
production:
A(x) --> [ -(uniform(0, 1)) F ] F(x) B(gauss(0, 1)) F(gauss(1, 0.1)) f(flip(0.5))
F(x) --> F(x) F(x)
endlsystem
"""
    # the axiom's + is first, - follows only a '[', B's argument is a module parameter, F is
    # rewritten by a production: only f is deferred, A's parameter passed on
    prog = program(text)
    assert sorted(prog.interpretation) == ["_late1"]
    assert prog.arity["_late1"] == 1


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("sometimes", "'turtle arguments:' is lazy or eager, got sometimes"),
        ("1", "expected a name"),
    ],
)
def test_a_bad_value_is_an_error_at_it(value: str, message: str) -> None:
    with pytest.raises(GrammarError) as info:
        compile_grammar(f"turtle arguments: {value}\nAxiom: F\n", filename="t.lsys")
    err = info.value
    assert message in str(err)
    assert (err.line, err.col) == (1, 19)


def test_eager_is_the_default_and_can_be_said() -> None:
    a = compile_grammar(BRANCH.replace("{lazy}", ""), filename="t.lsys")
    b = compile_grammar(BRANCH.replace("{lazy}", "turtle arguments: EAGER"), filename="t.lsys")
    assert not any(k.startswith("_late") for k in b.program().interpretation)
    assert a.program().sites == b.program().sites
