"""The compiled kernels (ngpm_runtime/kernels.py) against the numpy code they replaced
(tests/reference/): many seeded random primitive sets, drawn in lockstep into both, give
the same images, pyramids, draw batches, shape and circuit likelihoods, feature rows and
resampling ancestors bit for bit, but for the feature columns of sin/cos, allowed 1 float32
ulp (numpy's and the C library's sin may differ in the last bit on some machines)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from blocked_imports import run_blocked
from ngpm_runtime import kernels
from ngpm_runtime.image.features import FeatureMaker
from ngpm_runtime.image.raster import Canvas, prim_mask, rasterize
from ngpm_runtime.inference.likelihood import CircuitLikelihood, ShapeLikelihood
from ngpm_runtime.inference.resample import SCHEMES, resample
from reference import features as ref_features
from reference import likelihood as ref_likelihood
from reference import raster as ref_raster
from reference import resample as ref_resample

VP = (-12.0, 12.0, -22.0, 2.0)
# the numpy reference warns on the odd inputs (NaN, inf) the tests feed it
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")
ODD = [np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0]


def _coord(rng: np.random.Generator, lo: float, hi: float) -> float:
    """Mostly inside [lo, hi] with a margin, sometimes an odd value."""
    if rng.random() < 0.03:
        return float(ODD[rng.integers(len(ODD))])
    return float(rng.uniform(lo - 4, hi + 4))


def random_prim(rng: np.random.Generator) -> tuple:
    """A primitive of any kind, odd ones included (zero length or width, negative sizes,
    non-finite or huge coordinates, degenerate polygons)."""
    kind = ("seg", "seg", "seg", "leaf", "disk", "poly")[rng.integers(6)]
    x, y = _coord(rng, -12, 12), _coord(rng, -22, 2)
    if kind == "seg":
        a = rng.uniform(0, 2 * math.pi)
        ln = 0.0 if rng.random() < 0.05 else rng.uniform(0, 5)
        return (
            "seg",
            x,
            y,
            x + ln * math.cos(a),
            y + ln * math.sin(a),
            float(rng.choice([0.0, rng.uniform(0.05, 2.0), -0.7])),
        )
    if kind == "leaf":
        return ("leaf", x, y, _coord(rng, -400, 400), rng.uniform(-3, 3), rng.uniform(-1.5, 1.5))
    if kind == "disk":
        return ("disk", x, y, rng.uniform(-0.5, 2.5))
    m = int(rng.integers(1, 7))
    pts = [
        (x + rng.uniform(-3, 3), y + float(rng.choice([0.0, rng.uniform(-3, 3)]))) for _ in range(m)
    ]
    return ("poly", tuple(pts))


def _target(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    t = np.zeros((h, w), dtype=bool)
    t[h // 4 : 3 * h // 4, w // 5 : 4 * w // 5] = True
    t |= rng.random((h, w)) < 0.1
    return t


def _same_batch(got, want) -> None:
    np.testing.assert_array_equal(got.idx, want.idx)
    np.testing.assert_array_equal(got.y0, want.y0)
    np.testing.assert_array_equal(got.x0, want.x0)
    np.testing.assert_array_equal(got.new, want.new)
    np.testing.assert_array_equal(got.bbox, want.bbox)  # NaNs compare equal here
    for a, b in zip(got.hits(1000), want.hits(1000), strict=True):  # width: any
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("size", [(50, 50), (37, 23), (9, 13)])
@pytest.mark.parametrize("seed", range(12))
def test_draw_likelihoods_and_take_match_numpy(seed: int, size: tuple[int, int]) -> None:
    rng = np.random.default_rng(seed)
    h, w = size
    n = 7
    target = _target(rng, h, w)
    pyr = bool(seed % 3)
    new, old = Canvas(n, h, w, VP, pyramid=pyr), ref_raster.Canvas(n, h, w, VP, pyramid=pyr)
    likes = [
        (ShapeLikelihood(target, VP), ref_likelihood.ShapeLikelihood(target, VP)),
        (CircuitLikelihood(VP), ref_likelihood.CircuitLikelihood(VP)),
    ]
    states = [(a.start(n), b.start(n)) for a, b in likes]
    for _ in range(14):
        idx = np.sort(rng.choice(n, size=int(rng.integers(1, n + 1)), replace=False))
        prims = [random_prim(rng) for _ in idx]
        if rng.random() < 0.3:  # one kind only: the packing's fast path
            prims = [
                ("seg",) + p[1:] if p[0] == "seg" else ("disk", 0.0, -10.0, 1.5) for p in prims
            ]
        got, want = new.draw(idx, prims), old.draw(idx, prims)
        _same_batch(got, want)
        np.testing.assert_array_equal(new.image, old.image)
        np.testing.assert_array_equal(new.padded, old.padded)
        for (a, b), (sa, sb) in zip(likes, states, strict=True):
            da, db = a.increment(sa, new, got), b.increment(sb, old, want)
            np.testing.assert_array_equal(da, db)  # NaNs compare equal here
            for key in sa:
                np.testing.assert_array_equal(sa[key], sb[key])
        anc = np.sort(rng.integers(0, n, n))
        new.take(anc)
        old.take(anc)
        for sa, sb in states:
            for key in sa:
                sa[key], sb[key] = sa[key][anc], sb[key][anc]
        np.testing.assert_array_equal(new.image, old.image)
        np.testing.assert_array_equal(new.padded, old.padded)


def test_rasterize_and_prim_mask_match_numpy() -> None:
    rng = np.random.default_rng(5)
    for _ in range(30):
        prims = [random_prim(rng) for _ in range(int(rng.integers(0, 150)))]
        np.testing.assert_array_equal(
            rasterize(prims, VP, 40, 30), ref_raster.rasterize(prims, VP, 40, 30)
        )
        for p in prims[:5]:
            got, want = prim_mask(p, VP, 40, 30), ref_raster.prim_mask(p, VP, 40, 30)
            assert got[:2] == want[:2]
            np.testing.assert_array_equal(got[2], want[2])


def test_draw_rejects_bad_rows() -> None:
    canvas = Canvas(3, 20, 20, VP)
    with pytest.raises(IndexError):
        canvas.draw(np.array([3]), [("disk", 0.0, -10.0, 1.0)])
    with pytest.raises(ValueError, match="unknown primitive kind"):
        canvas.draw(np.array([0]), [("blob", 0.0)])
    with pytest.raises(IndexError):
        canvas.take(np.array([0, 1, 5]))


def _turtles(rng: np.random.Generator, m: int) -> np.ndarray:
    t = np.column_stack(
        [
            rng.uniform(-16, 16, m),
            rng.uniform(-26, 6, m),
            rng.uniform(-800, 800, m),
            rng.uniform(0, 2, m),
        ]
    )
    odd = rng.random((m, 3)) < 0.04
    t[:, :3][odd] = rng.choice(ODD, size=int(odd.sum()))
    t[rng.random(m) < 0.1, 2] = rng.choice([0.0, -360.0, 720.0, 90.0, -0.0])
    return t


@pytest.mark.parametrize("context", [False, True, "far"])
@pytest.mark.parametrize("seed", range(8))
def test_feature_rows_match_numpy(seed: int, context: bool | str) -> None:
    rng = np.random.default_rng(100 + seed)
    h, w = [(50, 50), (37, 23), (6, 11)][seed % 3]
    n = 9
    canvas = Canvas(n, h, w, VP)
    for _ in range(20):
        idx = np.sort(rng.choice(n, size=5, replace=False))
        canvas.draw(idx, [random_prim(rng) for _ in idx])
    program = SimpleNamespace(derivation_length=400)
    target = _target(rng, h, w) if seed % 4 else None
    for cv in (canvas, None):
        far = context == "far"
        a = FeatureMaker(program, VP, target, bool(context), far)  # type: ignore[arg-type]
        b = ref_features.FeatureMaker(program, VP, target, bool(context), far)  # type: ignore[arg-type]
        m = 40
        idx = rng.integers(0, n, m)
        turtle, depth = _turtles(rng, m), rng.integers(-1, 400, m).astype(np.float64)
        got, want = a._common(cv, idx, turtle, depth), b._common(cv, idx, turtle, depth)
        trig = [3, 4]
        np.testing.assert_array_max_ulp(got[:, trig], want[:, trig], maxulp=1)
        got[:, trig] = want[:, trig]
        np.testing.assert_array_equal(got, want)


def test_feature_rows_without_an_image() -> None:
    program = SimpleNamespace(derivation_length=10)
    rng = np.random.default_rng(3)
    turtle = _turtles(rng, 6)
    for target in (None, np.ones((0, 0), dtype=bool)):
        a = FeatureMaker(program, VP, target, True, True)  # type: ignore[arg-type]
        b = ref_features.FeatureMaker(program, VP, target, True, True)  # type: ignore[arg-type]
        got = a._common(None, np.arange(6), turtle, np.arange(6.0))
        want = b._common(None, np.arange(6), turtle, np.arange(6.0))
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("context", [False, True, "far"])
@pytest.mark.parametrize("seed", range(4))
def test_site_rows_of_a_round_match_numpy(seed: int, context: bool | str) -> None:
    """features_round (one kernel call for several sites: the module parameters and prior
    arguments written between the turtle and window columns) gives the numpy reference's
    rows, arguments of other widths (truncated or zero-padded) and empty images included."""
    rng = np.random.default_rng(300 + seed)
    h, w = [(50, 50), (37, 23)][seed % 2]
    n = 8
    canvas = Canvas(n, h, w, VP)
    for _ in range(10):
        canvas.draw(np.arange(n), [random_prim(rng) for _ in range(n)])
    program = SimpleNamespace(derivation_length=40)
    sites = [
        SimpleNamespace(arity=1, n_args=lambda: 2),
        SimpleNamespace(arity=0, n_args=lambda: 3),
        SimpleNamespace(arity=2, n_args=lambda: 1),
    ]
    target = _target(rng, h, w) if seed % 3 else None
    ms = [3, 4, 2]
    params = [rng.normal(size=(3, 1)), np.zeros((4, 0)), rng.normal(size=(2, 3))]  # 3: cut
    args = [rng.normal(size=(3, 2)), rng.random((4, 3)), rng.normal(size=(2, 0))]  # 0: pad
    for cv in (canvas, None):
        far = context == "far"
        a = FeatureMaker(program, VP, target, bool(context), far)  # type: ignore[arg-type]
        b = ref_features.FeatureMaker(program, VP, target, bool(context), far)  # type: ignore[arg-type]
        idx = rng.integers(0, n, sum(ms))
        turtle, depth = _turtles(rng, sum(ms)), rng.integers(-1, 40, sum(ms)).astype(np.float64)
        got = a.features_round(sites, cv, idx, turtle, depth, params, args)  # type: ignore[arg-type]
        want = b.features_round(sites, cv, idx, turtle, depth, params, args)  # type: ignore[arg-type]
        for g, wnt in zip(got, want, strict=True):
            assert g.shape == wnt.shape and g.dtype == np.float32
            trig = [3, 4]
            np.testing.assert_array_max_ulp(g[:, trig], wnt[:, trig], maxulp=1)
            g = g.copy()
            g[:, trig] = wnt[:, trig]
            np.testing.assert_array_equal(g, wnt)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_guide_round_log_prior_matches_prior_logpdf() -> None:
    """guide_round's log prior of its draws equals distributions.prior_logpdf to rounding (odd prior
    arguments included: point masses, a == b, zero weights) and it names the first row
    whose arguments a prior cannot take."""
    from ngpm_runtime.inference.distributions import prior_logpdf
    from ngpm_runtime.inference.sitekinds import KINDS
    from ngpm_runtime.program import Site

    rng = np.random.default_rng(9)
    n = 300
    cases = {
        "normal": np.column_stack([rng.normal(size=n), rng.choice([0.0, 0.5, 3.0, -2.0], n)]),
        "uniform": np.column_stack([rng.normal(size=n), rng.choice([0.0, 1.0, -1.0], n)]),
        "bernoulli": rng.choice([0.0, 0.3, 1.0], (n, 1)),
        "categorical": rng.choice([0.0, 1.0, 2.5], (n, 4)) + np.eye(4)[rng.integers(0, 4, n)],
    }
    cases["uniform"][:, 1] += cases["uniform"][:, 0]
    for kind, args in cases.items():
        table = KINDS[kind]
        site = Site(index=0, id=kind, kind=kind, k=4)
        params = rng.normal(size=(n, 9)) if table.head == "mixture" else rng.random((n, 4))
        out = np.empty((n, 3))
        bad = kernels.guide_round(
            np.zeros((0, 0), np.float32),
            np.zeros(n, np.int64),
            np.zeros((1, kernels.NET_COLS), np.int64),
            np.zeros(0, np.float32),
            np.zeros(0, np.int64),
            np.array([table.code]),
            np.ones(2),
            params.copy(),
            np.full(n, params.shape[1] if kind != "bernoulli" else 1),
            args,
            np.full(n, args.shape[1]),
            rng.random(n),
            rng.standard_normal(n),
            out,
        )
        assert bad == -1
        # to rounding: the kernel's log may round a last bit apart from numpy's
        want = prior_logpdf(site, args, out[:, 0])
        np.testing.assert_allclose(out[:, 2], want, rtol=1e-13, atol=1e-15)
    args = np.ones((5, 4))
    args[3] = [0.0, -1.0, 2.0, 1.0]
    out = np.empty((5, 3))
    bad = kernels.guide_round(
        np.zeros((0, 0), np.float32),
        np.zeros(5, np.int64),
        np.zeros((1, kernels.NET_COLS), np.int64),
        np.zeros(0, np.float32),
        np.zeros(0, np.int64),
        np.array([KINDS["categorical"].code]),
        np.ones(2),
        np.full((5, 4), 0.25),
        np.full(5, 4),
        args,
        np.full(5, 4),
        rng.random(5),
        np.zeros(0),
        out,
    )
    assert bad == 3


def test_kind_codes_match_the_kernels() -> None:
    from ngpm_runtime.inference.sitekinds import KINDS

    codes = {k: t.code for k, t in KINDS.items()}
    assert codes == {
        "normal": kernels.NORMAL,
        "uniform": kernels.UNIFORM,
        "bernoulli": kernels.BERNOULLI,
        "categorical": kernels.CATEGORICAL,
    }


def test_resampling_matches_numpy() -> None:
    rng = np.random.default_rng(11)
    for trial in range(300):
        m = int(rng.integers(1, 700 if trial % 10 == 0 else 40))
        log_w = rng.normal(0, float(rng.choice([0.1, 3.0, 300.0])), m)
        log_w[rng.random(m) < 0.2] = -np.inf
        if not np.isfinite(log_w).any():
            log_w[0] = 0.0
        n = m if trial % 3 else int(rng.integers(1, 60))
        seed = int(rng.integers(2**31))
        for scheme in SCHEMES:
            got = resample(scheme, log_w, np.random.default_rng(seed), n)
            want = ref_resample.resample(scheme, log_w, np.random.default_rng(seed), n)
            np.testing.assert_array_equal(got, want)


def test_ess_matches_numpy() -> None:
    """kernels.ess (what a run with kernels computes each step) is run._ess's numpy
    arithmetic: the same ESS and log sum exp, bit for bit, zero weights included."""
    from ngpm_runtime.inference.run import _ess

    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 8, 9, 10, 130, 600, 2000):
        for scale in (0.1, 10.0, 1e3):
            a = rng.standard_normal(n) * scale
            a[rng.random(n) < 0.2] = -np.inf
            m = float(np.max(a))
            assert kernels.ess(a, m) == _ess(a, m)
    dead = np.full(4, -np.inf)
    assert kernels.ess(dead, -np.inf) == _ess(dead, -np.inf) == (0.0, -np.inf)


def test_numpy_order_sum() -> None:
    rng = np.random.default_rng(2)
    for m in [1, 7, 8, 9, 127, 128, 129, 255, 256, 1000, 4099]:
        a = np.exp(rng.normal(0, 8, m))
        assert kernels._pairwise_sum(a) == a.sum()


def test_help_and_runtime_import_load_no_numba(tmp_path) -> None:
    body = """
import ngpm_runtime
from ngpm_runtime.inference import smc, likelihood
from ngpm_runtime.image import raster, features
from ngpm_compiler.cli import main
try:
    main(["--help"])
except SystemExit:
    pass
"""
    proc = run_blocked(body, tmp_path, blocked=("numba", "llvmlite"), timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("ok")


def test_loading_the_kernels_imports_no_scipy_linalg() -> None:
    """numba's BLAS probe would import scipy.linalg (0.3-0.4 s) at the first kernel call;
    kernels.py hides it while numba's array typing loads, and leaves a loaded one alone."""
    code = """
import sys
import numpy as np
{pre}
from ngpm_runtime import kernels
kernels.residual_counts(kernels.weights(np.zeros(4)), 4)
print("scipy.linalg" in sys.modules, sys.modules.get("scipy.linalg") is not None)
"""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    for pre, want in [("", "False False"), ("import scipy.linalg", "True True")]:
        proc = subprocess.run(
            [sys.executable, "-c", code.format(pre=pre)],
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert proc.stdout.strip() == want


def _unpack_reference(blocks, n_turtle, shape):
    """unpack_round's rows by hand: (idx, site, turtle, depth, fitted extra, raw args)."""
    rows = []
    for s, rs in blocks:
        arity, na = shape[s]
        for i, depth, turtle, params, args in rs:
            fit = [*params[:arity], *[0.0] * (arity - len(params))]
            fit += [*args[:na], *[0.0] * (na - len(args))]
            rows.append((i, s, list(turtle), max(depth, 0.0), fit, list(args)))
    return rows


def test_unpack_round_rows_equal_the_packed_state() -> None:
    """kernels.unpack_round: blocks of several sites, parameters and arguments fitted to
    the site (cut, zero-padded) for the features and kept as they are for the guide, the
    axiom's depth -1 as 0; a malformed vector is an IndexError, not a crash."""
    rng = np.random.default_rng(5)
    shape = np.array([(1, 2), (0, 3), (2, 1)], dtype=np.int64)  # (arity, n_args) per site
    blocks = []
    for s, a, k in ((0, 1, 2), (1, 2, 4), (2, 1, 0)):  # site 1: extra parameter, 4 weights
        rs = [
            (int(i), float(rng.integers(-1, 9)), rng.normal(size=4), rng.normal(size=a),
             rng.normal(size=k))
            for i in rng.permutation(9)[:3]
        ]  # fmt: skip
        blocks.append((s, rs))
    flat = []
    for s, rs in blocks:
        flat += [s, len(rs), len(rs[0][3]), len(rs[0][4])]
        for i, depth, turtle, params, args in rs:
            flat += [i, depth, *turtle, *params, *args]
    n = 12
    bufs = dict(
        idx=np.zeros(n, np.intp), site=np.zeros(n, np.int64), turtle=np.zeros((n, 4)),
        depth=np.zeros(n), extra=np.zeros((n, 3)), n_extra=np.zeros(n, np.int64),
        args=np.zeros((n, 4)), n_args=np.zeros(n, np.int64),
    )  # fmt: skip
    got = kernels.unpack_round(np.array(flat), 4, shape, *bufs.values())
    want = _unpack_reference(blocks, 4, shape)
    assert got == len(want) == 9
    for r, (i, s, turtle, depth, fit, args) in enumerate(want):
        assert bufs["idx"][r] == i and bufs["site"][r] == s and bufs["depth"][r] == depth
        assert bufs["turtle"][r].tolist() == turtle
        assert bufs["n_extra"][r] == len(fit) and bufs["extra"][r, : len(fit)].tolist() == fit
        assert bufs["n_args"][r] == len(args) and bufs["args"][r, : len(args)].tolist() == args
    for bad in (flat[:-1], [7.0, 1, 0, 0, 0, 0, 0, 0, 0, 0], flat + [0.0, 20.0, 0.0, 0.0]):
        with pytest.raises(IndexError):
            kernels.unpack_round(np.array(bad, dtype=np.float64), 4, shape, *bufs.values())


def test_add_weights_equals_the_numpy_update() -> None:
    """kernels.add_weights: log w += log p - log q (NaN, as inf - inf, gives -inf), log
    prior += log p; no log q (the prior proposal): log w unchanged."""
    rng = np.random.default_rng(2)
    odd = np.array([np.nan, np.inf, -np.inf, 0.0])
    for _ in range(50):
        n = 12
        log_w, log_p0 = rng.normal(size=n), rng.normal(size=n)
        idx = rng.permutation(n)[: rng.integers(1, n)].astype(np.intp)
        lq, lp = rng.normal(size=(2, len(idx)))
        lq[rng.random(len(idx)) < 0.2] = odd[rng.integers(4)]
        lp[rng.random(len(idx)) < 0.2] = odd[rng.integers(4)]
        for guided in (True, False):
            w, p = log_w.copy(), log_p0.copy()
            kernels.add_weights(w, p, idx, lq if guided else np.zeros(0), lp)
            want_w, want_p = log_w.copy(), log_p0.copy()
            if guided:
                with np.errstate(invalid="ignore"):
                    d = lp - lq
                np.add.at(want_w, idx, np.where(np.isnan(d), -np.inf, d))
            np.add.at(want_p, idx, lp)
            np.testing.assert_array_equal(w, want_w)
            np.testing.assert_array_equal(p, want_p)
    with pytest.raises(IndexError):
        kernels.add_weights(np.zeros(2), np.zeros(2), np.array([2]), np.zeros(1), np.zeros(1))
