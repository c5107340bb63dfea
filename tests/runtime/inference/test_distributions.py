"""Batched prior and proposal densities: normalization, sampling moments, edge cases."""

import numpy as np
import pytest
from ngpm_runtime.errors import ProgramError
from ngpm_runtime.inference.distributions import (
    prior_logpdf,
    prior_sample,
    proposal_draw,
    proposal_logpdf,
    proposal_sample,
    temper,
)
from ngpm_runtime.inference.sitekinds import KINDS, MIXTURE
from ngpm_runtime.program import Site

NORMAL = Site(index=0, id="n", kind="normal")
UNIFORM = Site(index=1, id="u", kind="uniform")
BERN = Site(index=2, id="b", kind="bernoulli")
CAT = Site(index=3, id="c", kind="categorical", k=3)


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(seed))


def test_normal_prior_logpdf_matches_formula() -> None:
    args = np.array([[1.0, 2.0], [0.0, 0.5]])
    x = np.array([2.0, -1.0])
    want = -0.5 * ((x - args[:, 0]) / args[:, 1]) ** 2 - np.log(args[:, 1] * np.sqrt(2 * np.pi))
    np.testing.assert_allclose(prior_logpdf(NORMAL, args, x), want)


def test_normal_prior_sample_moments() -> None:
    args = np.tile([3.0, 0.5], (40000, 1))
    v = prior_sample(NORMAL, args, rng())
    assert abs(v.mean() - 3.0) < 0.01 and abs(v.std() - 0.5) < 0.01


def test_zero_sigma_is_a_point_mass() -> None:
    args = np.array([[2.0, 0.0], [2.0, 0.0]])
    v = prior_sample(NORMAL, args, rng())
    assert np.all(v == 2.0)
    lp = prior_logpdf(NORMAL, args, np.array([2.0, 2.5]))
    assert lp[0] == 0.0 and lp[1] == -np.inf


def test_uniform_prior() -> None:
    args = np.tile([-1.0, 3.0], (5, 1))
    v = prior_sample(UNIFORM, args, rng())
    assert np.all((v >= -1) & (v <= 3))
    lp = prior_logpdf(UNIFORM, args, np.array([0.0, 3.0, -1.0, 3.5, -2.0]))
    np.testing.assert_allclose(lp[:3], -np.log(4.0))
    assert np.all(lp[3:] == -np.inf)


def test_bernoulli_prior() -> None:
    args = np.tile([0.3], (50000, 1))
    v = prior_sample(BERN, args, rng())
    assert set(np.unique(v)) <= {0.0, 1.0}
    assert abs(v.mean() - 0.3) < 0.01
    lp = prior_logpdf(BERN, args[:3], np.array([1.0, 0.0, 0.5]))
    np.testing.assert_allclose(lp[:2], np.log([0.3, 0.7]))
    assert lp[2] == -np.inf


def test_categorical_prior_normalizes_weights() -> None:
    args = np.tile([1.0, 2.0, 1.0], (40000, 1))
    v = prior_sample(CAT, args, rng())
    freq = np.bincount(v.astype(int), minlength=3) / len(v)
    np.testing.assert_allclose(freq, [0.25, 0.5, 0.25], atol=0.01)
    lp = prior_logpdf(CAT, args[:4], np.array([0.0, 1.0, 3.0, 0.5]))
    np.testing.assert_allclose(lp[:2], np.log([0.25, 0.5]))
    assert lp[2] == -np.inf and lp[3] == -np.inf


def test_categorical_zero_weight_never_sampled() -> None:
    args = np.tile([1.0, 0.0, 1.0], (20000, 1))
    v = prior_sample(CAT, args, rng(3))
    assert not np.any(v == 1.0)


def test_bad_categorical_weights_raise_program_error() -> None:
    with pytest.raises(ProgramError):
        prior_sample(CAT, np.array([[0.0, 0.0, 0.0]]), rng())
    with pytest.raises(ProgramError):
        prior_logpdf(CAT, np.array([[1.0, -1.0, 1.0]]), np.array([0.0]))


def test_nonfinite_normal_args_raise_program_error() -> None:
    with pytest.raises(ProgramError):
        prior_sample(NORMAL, np.array([[np.nan, 1.0]]), rng())


def _integrate(f, lo, hi, n=200001):
    x = np.linspace(lo, hi, n)
    return np.trapezoid(f(x), x) if hasattr(np, "trapezoid") else np.trapz(f(x), x)


def test_normal_mixture_proposal_integrates_to_one_and_matches_samples() -> None:
    params = np.array([[0.0, np.log(3.0), -1.0, 2.0, np.log(0.5), np.log(2.0)]])
    args = np.array([[1.0, 2.0]])

    def dens(x):
        return np.exp(
            proposal_logpdf(NORMAL, np.repeat(args, len(x), 0), np.repeat(params, len(x), 0), x)
        )

    assert abs(_integrate(dens, -40, 40) - 1.0) < 1e-6
    n = 60000
    v = proposal_sample(NORMAL, np.repeat(args, n, 0), np.repeat(params, n, 0), rng())
    # mixture weights 1/4, 3/4; means mu + sigma * m = -1, 5
    assert abs(v.mean() - (0.25 * -1.0 + 0.75 * 5.0)) < 0.05


def test_uniform_logit_normal_proposal_integrates_to_one() -> None:
    params = np.array([[0.0, 0.0, 0.5, -1.0, 0.0, np.log(0.7)]])
    args = np.array([[-2.0, 3.0]])

    def dens(x):
        return np.exp(
            proposal_logpdf(UNIFORM, np.repeat(args, len(x), 0), np.repeat(params, len(x), 0), x)
        )

    assert abs(_integrate(dens, -2.0, 3.0) - 1.0) < 1e-4
    n = 20000
    v = proposal_sample(UNIFORM, np.repeat(args, n, 0), np.repeat(params, n, 0), rng())
    assert np.all((v > -2.0) & (v < 3.0))
    assert np.all(
        np.isfinite(proposal_logpdf(UNIFORM, np.repeat(args, n, 0), np.repeat(params, n, 0), v))
    )
    assert proposal_logpdf(UNIFORM, args, params, np.array([3.5]))[0] == -np.inf


def test_discrete_proposals() -> None:
    args = np.tile([1.0, 1.0, 1.0], (30000, 1))
    params = np.tile([0.1, 0.1, 0.8], (30000, 1))
    v = proposal_sample(CAT, args, params, rng())
    freq = np.bincount(v.astype(int), minlength=3) / len(v)
    np.testing.assert_allclose(freq, [0.1, 0.1, 0.8], atol=0.01)
    np.testing.assert_allclose(
        proposal_logpdf(CAT, args[:2], params[:2], np.array([2.0, 0.0])), np.log([0.8, 0.1])
    )
    bp = np.array([[0.9], [0.9]])
    np.testing.assert_allclose(
        proposal_logpdf(BERN, np.array([[0.5], [0.5]]), bp, np.array([1.0, 0.0])),
        np.log([0.9, 0.1]),
    )


def test_prior_draw_log_density_matches_prior_logpdf() -> None:
    from ngpm_runtime.inference.distributions import prior_draw

    cases = [
        (NORMAL, np.array([[1.0, 2.0], [0.0, 0.0], [3.0, -0.5]] * 10)),
        (UNIFORM, np.array([[0.0, 2.0], [1.0, 1.0], [3.0, -1.0]] * 10)),
        (BERN, np.array([[0.3], [0.0], [1.0]] * 10)),
        (CAT, np.array([[1.0, 2.0, 1.0], [0.0, 1.0, 3.0], [1.0, 0.0, 0.0]] * 10)),
        (CAT, np.tile([0.2, 0.0, 0.8], (30, 1))),
    ]
    for site, args in cases:
        v, lp = prior_draw(site, args, rng(1))
        np.testing.assert_allclose(lp, prior_logpdf(site, args, v))
        assert np.all(np.isfinite(lp))
        np.testing.assert_array_equal(v, prior_sample(site, args, rng(1)))


def test_proposal_draw_log_q_equals_proposal_logpdf() -> None:
    """The fused draw returns the proposal density of its own values (the compiled kernel
    and numpy's logpdf may round a last bit apart, as LLVM's and numpy's log/exp do)."""
    r = rng(3)
    n = 40
    k3 = 3  # mixture components
    mix = np.hstack([r.normal(size=(n, k3)), r.normal(size=(n, k3)), r.normal(size=(n, k3))])
    cat = r.random((n, 3))
    cat[0] = [0.0, 0.0, 0.0]  # falls back to uniform
    cat[1] = [0.0, 2.0, 0.0]  # one possible value
    cat[2] = [-1.0, 1.0, 1.0]  # negative weights clip to zero
    cases = [
        (NORMAL, np.column_stack([r.normal(size=n), r.random(n) + 0.1]), mix),
        (UNIFORM, np.column_stack([-r.random(n), r.random(n) + 0.5]), mix),
        (BERN, r.random((n, 1)), r.random((n, 1))),
        (CAT, np.ones((n, 3)), cat),
    ]
    for site, args, params in cases:
        values, log_q = proposal_draw(site, args, params, rng(7))
        want = proposal_logpdf(site, args, params, values)
        np.testing.assert_allclose(log_q, want, rtol=1e-13, atol=1e-13)
        assert np.isfinite(log_q).all()
        # the same values as proposal_sample from the same generator state
        np.testing.assert_array_equal(values, proposal_sample(site, args, params, rng(7)))
    v, _ = proposal_draw(CAT, np.ones((n, 3)), cat, rng(1))
    assert v[1] == 1.0 and v[2] != 0.0


def test_categorical_prior_logpdf_shared_rows() -> None:
    """The shared-distribution shortcut agrees with the row-by-row computation."""
    w = np.array([[1.0, 2.0, 5.0]])
    args = np.repeat(w, 6, axis=0)
    x = np.array([0.0, 1.0, 2.0, 2.0, 3.0, 0.5])
    shared = prior_logpdf(CAT, args, x)
    single = np.array([prior_logpdf(CAT, w, x[i : i + 1])[0] for i in range(6)])
    np.testing.assert_array_equal(shared, single)
    assert shared[4] == -np.inf and shared[5] == -np.inf


def _odd_params(r: np.random.Generator, site: Site, n: int) -> np.ndarray:
    """Proposal parameters of the site's kind, some rows odd (zero, negative, huge or NaN
    probabilities; huge, NaN or -inf log weights and log sds)."""
    if site.kind in ("normal", "uniform"):
        p = r.normal(size=(n, 9)) * 2
        p[r.random(n) < 0.1, 0] = -np.inf
        p[r.random(n) < 0.05, 7] = 800.0
        p[r.random(n) < 0.05, 4] = np.nan
        return p
    k = 1 if site.kind == "bernoulli" else 5
    p = r.random((n, k)) * r.choice([1e-3, 1.0, 1e3], size=(n, 1))
    p[r.random(n) < 0.1] = 0.0
    p[r.random(n) < 0.05, 0] = -0.5
    p[r.random(n) < 0.05, 0] = np.nan
    p[r.random(n) < 0.05, 0] = 1.5
    return p


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("site", [NORMAL, UNIFORM, BERN, CAT], ids=lambda s: s.kind)
def test_compiled_draws_match_the_numpy_reference(site: Site) -> None:
    """The kernel's draws (kernels.guide_round) against the numpy code they replaced
    (tests/reference/sitekinds.py), from the same generator state: the same values (to
    1e-12: the numpy path's few-row branches round differently), log q and tempering to
    1e-12, odd parameters included; per row, so rows drawn 4 at a time give what 200 at
    once give."""
    from reference import sitekinds as ref

    r = rng(11)
    n = 200
    args = {
        "normal": np.column_stack([r.normal(size=n) * 10, r.random(n) * 5]),
        "uniform": np.column_stack([-r.random(n), r.random(n) * 2]),
        "bernoulli": r.random((n, 1)),
        "categorical": np.ones((n, 5)),
    }[site.kind]
    table, old = KINDS[site.kind], ref.KINDS[site.kind]
    for _ in range(5):
        params = _odd_params(r, site, n)
        v, q = proposal_draw(site, args, params, rng(5))
        rv, rq = old.proposal_draw(args, params, rng(5))
        np.testing.assert_allclose(v, rv, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(q, rq, rtol=1e-12, atol=1e-12)
        g = rng(5)
        parts = [proposal_draw(site, args[i : i + 4], params[i : i + 4], g) for i in range(0, n, 4)]
        if table.head != MIXTURE:  # a mixture draws its normals after its uniforms
            np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), v)
        for t, tc in ((0.5, 0.3), (2.0, 4.0)):
            np.testing.assert_allclose(
                table.temper(params, t, tc), old.temper(params, t, tc), rtol=1e-12, atol=1e-12
            )


def test_temper_choices_raise_probabilities_to_a_power() -> None:
    p = np.array([[0.2, 0.3, 0.5], [0.0, 0.25, 0.75], [0.0, 0.0, 0.0]])
    q = temper("categorical", p, choice_temperature=0.5)
    want = p[:2] ** 2 / (p[:2] ** 2).sum(axis=1, keepdims=True)
    np.testing.assert_allclose(q[:2], want)
    assert q[1, 0] == 0.0  # an impossible choice stays impossible
    np.testing.assert_array_equal(q[2], p[2])  # an all-zero row is left to _probs
    b = temper("bernoulli", np.array([[0.8], [1.0], [0.0]]), choice_temperature=0.5)
    np.testing.assert_allclose(b[:, 0], [0.64 / (0.64 + 0.04), 1.0, 0.0])
    assert temper("categorical", p, temperature=0.3) is p  # mixtures' T does not touch choices
    # flatter than 1 moves toward uniform; log q stays a normalized distribution
    flat = temper("categorical", p[:1], choice_temperature=4.0)
    assert flat[0, 0] > p[0, 0] and np.isclose(flat.sum(), 1.0)


def test_temper_mixture_scales_weights_and_sds() -> None:
    k = 2
    params = np.array([[0.0, 1.0, -0.5, 0.5, 0.1, -0.3]])
    out = temper("normal", params, temperature=0.25, choice_temperature=0.1)
    np.testing.assert_allclose(out[:, :k], params[:, :k] / 0.25)
    np.testing.assert_allclose(out[:, k : 2 * k], params[:, k : 2 * k])
    np.testing.assert_allclose(np.exp(out[:, 2 * k :]), np.exp(params[:, 2 * k :]) * 0.5)
    assert temper("uniform", params, temperature=1.0) is params
    # one component: exactly the density to the power 1/T, renormalized (a narrower normal)
    one = np.array([[0.0, 0.4, np.log(0.7)]])
    args = np.array([[1.0, 2.0]])
    xs = np.linspace(-8, 10, 4001)
    t = 0.5
    got = proposal_logpdf(
        NORMAL,
        np.repeat(args, len(xs), 0),
        np.repeat(temper("normal", one, temperature=t), len(xs), 0),
        xs,
    )
    base = proposal_logpdf(NORMAL, np.repeat(args, len(xs), 0), np.repeat(one, len(xs), 0), xs)
    powered = base / t
    powered -= np.log(np.sum(np.exp(powered)) * (xs[1] - xs[0]))
    np.testing.assert_allclose(got, powered, atol=1e-6)
