"""SMC against exact answers: enumerated posteriors and evidence for tiny discrete grammars,
and a conjugate gaussian case, for every resampling scheme, ESS-triggered resampling, the prior
proposal and deliberately different proposals."""

import math

import numpy as np
import pytest
from fixtures.exact import check, enumerate_program, exact, gauss_exact, pooled, tv
from fixtures.tiny_programs import (
    TINY_LSYS,
    EndPointLikelihood,
    PotentialSumXLikelihood,
    SumXLikelihood,
    branch_program,
    discrete_program,
    gauss_program,
)
from ngpm_runtime.inference.distributions import prior_logpdf
from ngpm_runtime.inference.proposals import FixedProposal
from ngpm_runtime.inference.smc import SMCOptions, smc

# A proposal far from the prior at every discrete site of each grammar.
DISCRETE_Q = FixedProposal({0: [0.2, 0.8], 1: [0.6, 0.1, 0.3], 2: [0.8]})
BRANCH_Q = FixedProposal({0: [0.85], 1: [0.6], 2: [0.1, 0.3, 0.6]})

CASES = [
    ("multinomial", None, None),
    ("stratified", None, None),
    ("systematic", None, None),
    ("residual", None, None),
    ("systematic", 0.5, None),
    ("residual", None, "q"),
    ("stratified", 0.7, "q"),
]


def test_enumeration_is_a_distribution() -> None:
    for prog in (discrete_program(), branch_program()):
        runs = enumerate_program(prog)
        assert abs(sum(math.exp(lp) for _, lp in runs) - 1.0) < 1e-12
        assert len(runs) > 5


@pytest.mark.parametrize(("scheme", "ess", "prop"), CASES)
def test_discrete_posterior_and_evidence(scheme, ess, prop) -> None:
    prog = discrete_program()
    like = SumXLikelihood(goal=2.0, scale=1.0)
    want_post, want_log_z = exact(prog, like)
    post, log_z = pooled(prog, like, DISCRETE_Q if prop else None, scheme, ess, seed=10)
    assert check(post, log_z, want_post, want_log_z, 0.06), (tv(post, want_post), log_z, want_log_z)


@pytest.mark.parametrize(("scheme", "ess", "prop"), CASES[2:])
def test_branch_cut_halt_posterior_and_evidence(scheme, ess, prop) -> None:
    prog = branch_program()
    like = SumXLikelihood(goal=2.5, scale=1.0)
    want_post, want_log_z = exact(prog, like)
    post, log_z = pooled(prog, like, BRANCH_Q if prop else None, scheme, ess, seed=20)
    assert check(post, log_z, want_post, want_log_z, 0.08), (tv(post, want_post), log_z, want_log_z)


def test_exact_check_detects_ignored_proposal_weights() -> None:
    # guard: the tolerances notice a proposal whose log q is wrongly reported as the prior's
    class Unweighted(FixedProposal):
        def propose(self, site, args, feats, rng):
            v, _ = super().propose(site, args, feats, rng)
            return v, prior_logpdf(site, args, v)

    for prog, like, q in (
        (discrete_program(), SumXLikelihood(2.0, 1.0), DISCRETE_Q),
        (branch_program(), SumXLikelihood(2.5, 1.0), BRANCH_Q),
    ):
        want_post, want_log_z = exact(prog, like)
        post, log_z = pooled(prog, like, Unweighted(q.params), "residual", None)
        assert not check(post, log_z, want_post, want_log_z, 0.08)


@pytest.mark.parametrize(("scheme", "ess", "prop"), CASES[3:])
def test_a_potential_that_settles_keeps_posterior_and_evidence_exact(scheme, ess, prop) -> None:
    """Weights that follow a potential while particles derive (an intermediate target far
    from the likelihood) and the likelihood itself once they finish (Likelihood.settle) are
    exact: on a grammar whose particles finish at different steps (branch_program's halt)
    and one where all finish together."""
    for prog, goal, q, tol in (
        (branch_program(), 2.5, BRANCH_Q, 0.08),
        (discrete_program(), 2.0, DISCRETE_Q, 0.06),
    ):
        like = PotentialSumXLikelihood(goal=goal, scale=1.0)
        want_post, want_log_z = exact(prog, like)
        post, log_z = pooled(prog, like, q if prop else None, scheme, ess, seed=30)
        assert check(post, log_z, want_post, want_log_z, tol), (
            tv(post, want_post),
            log_z,
            want_log_z,
        )


def test_exact_check_detects_a_potential_never_settled() -> None:
    for prog, goal in ((branch_program(), 2.5), (discrete_program(), 2.0)):
        like = PotentialSumXLikelihood(goal=goal, scale=1.0, settles=False)
        want_post, want_log_z = exact(prog, like)
        post, log_z = pooled(prog, like, None, "residual", None, seed=30)
        assert not check(post, log_z, want_post, want_log_z, 0.08)


def test_smc_weights_are_all_equal_to_evidence_without_likelihood() -> None:
    # no likelihood, prior proposal: every weight is 0 and log Z is exactly 0
    r = smc(discrete_program(), None, 200, options=SMCOptions(seed=1))
    assert r.log_evidence == 0.0 and np.all(r.log_weights == 0.0)
    # a different proposal without likelihood: Z estimates 1 (log Z near 0)
    r = smc(discrete_program(), None, 4000, DISCRETE_Q, options=SMCOptions(seed=1))
    assert abs(r.log_evidence) < 0.05


@pytest.mark.parametrize("prop", [None, "q"])
def test_gaussian_lengths_posterior_and_evidence(prop) -> None:
    obs, sd = [1.8, 1.5], [0.4, 0.3]
    like = EndPointLikelihood(obs, sd)
    want_mean, want_log_z = gauss_exact(obs, sd)
    # q: a two-component mixture in prior units, wider and shifted
    q = FixedProposal({0: [0.0, 0.0, -0.5, 1.0, 0.3, 0.3], 1: [0.0, 0.5, -0.5, 0.3, 0.4, 0.0]})
    r = smc(
        gauss_program(),
        like,
        8000,
        q if prop else None,
        options=SMCOptions(ess_from_proposal=True, seed=3, resample="systematic"),
    )
    w = np.exp(r.log_weights - r.log_weights.max())
    w /= w.sum()
    first = np.array([p.primitives[0][3] for p in r.particles])
    assert abs(float(w @ first) - want_mean) < 0.03
    assert abs(r.log_evidence - want_log_z) < 0.05


@pytest.mark.parametrize(
    ("scheme", "ess", "prop"), [("residual", None, None), ("systematic", 0.5, "q")]
)
def test_compiled_grammar_posterior_and_evidence(scheme, ess, prop) -> None:
    # groups, a categorical, flips, cut, halt and a random interpretation rule, compiled
    from ngpm_compiler.language.compile import compile_grammar

    prog = compile_grammar(TINY_LSYS, filename="tiny.lsys").program()
    assert [s.id for s in prog.sites][-1] == "interp:L/0/bernoulli0"
    q = FixedProposal({0: [0.3, 0.7], 1: [0.2, 0.2, 0.6], 2: [0.7], 3: [0.4, 0.6], 4: [0.9]})
    like = SumXLikelihood(goal=3.0, scale=1.5)
    want_post, want_log_z = exact(prog, like)
    assert len(want_post) > 10
    post, log_z = pooled(prog, like, q if prop else None, scheme, ess, seed=30)
    assert check(post, log_z, want_post, want_log_z, 0.08), (tv(post, want_post), log_z, want_log_z)
