"""FeatureMaker against a slow, direct computation of section 6's features."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ngpm_runtime.image.features import (
    FAR_DIST,
    N_CONTEXT,
    N_FAR,
    RAY_ANGLES,
    RAY_DIST,
    FeatureMaker,
)
from ngpm_runtime.image.raster import Canvas
from ngpm_runtime.program import Program, Site

VP = (-12.0, 12.0, -22.0, 2.0)


def _program() -> Program:
    sites = [
        Site(index=0, id="B/0/normal0", kind="normal", arity=1),
        Site(index=1, id="L/choice", kind="categorical", k=3, arity=0),
    ]
    return Program(
        name="t", sites=sites, axiom=lambda ctx: [("S",)], productions={}, derivation_length=40
    )


def _slow_level(img: np.ndarray, lv: int) -> np.ndarray:
    s = 2**lv
    h, w = img.shape[0] // s, img.shape[1] // s
    out = np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            out[r, c] = img[r * s : (r + 1) * s, c * s : (c + 1) * s].mean()
    return out


def _slow_windows(img: np.ndarray, x: float, y: float) -> list[float]:
    u = (x - VP[0]) / (VP[1] - VP[0])
    v = (VP[3] - y) / (VP[3] - VP[2])
    vals = []
    for lv in range(4):
        lev = _slow_level(img.astype(float), lv)
        h, w = lev.shape
        r0, c0 = math.floor(v * h), math.floor(u * w)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                r, c = r0 + dr, c0 + dc
                vals.append(lev[r, c] if 0 <= r < h and 0 <= c < w else -1.0)
    return vals


def _slow_context(
    img: np.ndarray, target: np.ndarray, x: float, y: float, heading: float, far: bool = False
) -> list[float]:
    """The context group (and the far group after it) by its definition, one number at a
    time: look-ahead on level 1, the far one's on level 3."""
    t2, c2 = _slow_level(target.astype(float), 2), _slow_level(img.astype(float), 2)
    total = t2.sum()
    vals = [np.maximum(t2 - c2, 0).sum() / total, np.maximum(c2 - t2, 0).sum() / total]
    for dists, lv in [(RAY_DIST, 1)] + [(FAR_DIST, 3)] * far:
        tl, cl = _slow_level(target.astype(float), lv), _slow_level(img.astype(float), lv)
        h, w = tl.shape
        for a in RAY_ANGLES:
            for d in dists:
                px = x + d * 24 * math.cos(math.radians(heading + a))
                py = y + d * 24 * math.sin(math.radians(heading + a))
                r = math.floor((VP[3] - py) / 24 * h)
                c = math.floor((px - VP[0]) / 24 * w)
                inside = 0 <= r < h and 0 <= c < w
                vals.append(max(tl[r, c] - cl[r, c], 0.0) if inside else -1.0)
    return vals


def _slow_row(site: Site, img, target, turtle, depth, params, args) -> list[float]:
    x, y, h, w = turtle
    local = [
        2 * (x + 12) / 24 - 1,
        2 * (y + 22) / 24 - 1,
        (h % 360) / 180 - 1,
        math.sin(math.radians(h)),
        math.cos(math.radians(h)),
        w,
        depth / 40,
    ]
    local += list(params) + list(args)
    tf = _slow_windows(target, x, y) if target is not None else [0.0] * 36
    return local + tf + _slow_windows(img, x, y)


def test_features_match_slow_computation() -> None:
    rng = np.random.default_rng(0)
    prog = _program()
    target = np.zeros((50, 50), dtype=bool)
    target[10:45, 20:30] = True
    n = 7
    canvas = Canvas(n, 50, 50, VP)
    for _ in range(15):
        prims = [
            ("disk", rng.uniform(-12, 12), rng.uniform(-22, 2), rng.uniform(0.5, 3))
            for _ in range(n)
        ]
        canvas.draw(np.arange(n), prims)
    # positions inside, on the border and outside the viewport
    xs = np.array([0.0, -11.9, 11.99, -13.0, 5.0, 0.3, 30.0])
    ys = np.array([-10.0, 1.9, -21.95, -10.0, 2.5, -0.1, 0.0])
    turtle = np.stack([xs, ys, rng.uniform(-400, 400, n), rng.uniform(0.1, 1, n)], axis=1)
    depth = rng.integers(0, 40, n).astype(float)
    idx = np.array([6, 0, 3, 2, 2, 5, 1])
    for tmask, context in (
        (target, False),
        (None, False),
        (target, True),
        (None, True),
        (target, "far"),
        (None, "far"),
    ):
        far = context == "far"
        fm = FeatureMaker(prog, VP, tmask, context=bool(context), far=far)
        for site, params, args in (
            (prog.sites[0], rng.normal(size=(n, 1)), rng.normal(size=(n, 2))),
            (prog.sites[1], np.zeros((n, 0)), np.tile([0.2, 0.3, 0.5], (n, 1))),
        ):
            got = fm.features(site, canvas, idx, turtle, depth, params, args)
            assert got.dtype == np.float32
            assert got.shape == (n, fm.n_features(site))
            for k in range(n):
                want = _slow_row(
                    site, canvas.image[idx[k]], tmask, turtle[k], depth[k], params[k], args[k]
                )
                if context:
                    want += (
                        [0.0] * (N_CONTEXT + N_FAR * far)
                        if tmask is None
                        else _slow_context(canvas.image[idx[k]], tmask, *turtle[k, :3], far)
                    )
                np.testing.assert_allclose(got[k], want, rtol=1e-5, atol=1e-6)


def test_features_round_rows_equal_features_per_site() -> None:
    """One pass for several sites gives each site's rows exactly as `features` alone."""
    rng = np.random.default_rng(3)
    prog = _program()
    target = np.zeros((50, 50), dtype=bool)
    target[5:30, 10:40] = True
    canvas = Canvas(6, 50, 50, VP)
    canvas.draw(
        np.arange(6), [("disk", rng.uniform(-12, 12), rng.uniform(-22, 2), 2.0) for _ in range(6)]
    )
    fm = FeatureMaker(prog, VP, target)
    idx = np.array([4, 1, 1, 0, 5])
    turtle = np.column_stack(
        [
            rng.uniform(-14, 14, 5),
            rng.uniform(-24, 4, 5),
            rng.uniform(-400, 400, 5),
            rng.uniform(0.1, 1, 5),
        ]
    )
    depth = rng.integers(0, 40, 5).astype(float)
    sites = [prog.sites[0], prog.sites[1]]
    params = [rng.normal(size=(2, 1)), np.zeros((3, 0))]
    args = [rng.normal(size=(2, 2)), np.tile([0.2, 0.3, 0.5], (3, 1))]
    got = fm.features_round(sites, canvas, idx, turtle, depth, params, args)
    cut = [slice(0, 2), slice(2, 5)]
    for site, rows, par, arg, sl in zip(sites, got, params, args, cut, strict=True):
        want = fm.features(site, canvas, idx[sl], turtle[sl], depth[sl], par, arg)
        np.testing.assert_array_equal(rows, want)


def test_layout_slices() -> None:
    prog = _program()
    fm = FeatureMaker(prog, VP, None)
    lay = fm.layout(prog.sites[0])
    assert lay["local"] == slice(0, 10)
    assert lay["target"] == slice(10, 46)
    assert lay["partial"] == slice(46, 82)
    assert fm.layout(prog.sites[1])["local"] == slice(0, 10)
    assert fm.n_features(prog.sites[1]) == 82
    wide = FeatureMaker(prog, VP, None, context=True)
    assert wide.layout(prog.sites[0])["context"] == slice(82, 82 + N_CONTEXT)
    assert wide.n_features(prog.sites[1]) == 82 + N_CONTEXT == 99
    far = FeatureMaker(prog, VP, None, far=True)  # implies the context
    assert far.layout(prog.sites[0])["far"] == slice(99, 99 + N_FAR)
    assert far.n_features(prog.sites[1]) == 99 + N_FAR == 109 and far.context
    assert "context" not in lay


def test_no_canvas_no_target_gives_zero_windows() -> None:
    prog = _program()
    fm = FeatureMaker(prog, VP, None)
    site = prog.sites[1]
    got = fm.features(
        site,
        None,
        np.arange(2),
        np.zeros((2, 4)),
        np.zeros(2),
        np.zeros((2, 0)),
        np.full((2, 3), 1 / 3),
    )
    lay = fm.layout(site)
    assert not got[:, lay["target"]].any() and not got[:, lay["partial"]].any()
    np.testing.assert_allclose(got[:, 7:10], 1 / 3, rtol=1e-6)


@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")
def test_heading_not_finite_looks_ahead_outside() -> None:
    """Issue #27: a NaN or inf heading (from a damaged guide's proposal) gave an IndexError
    in the look-ahead; its look-ahead cells now read as outside the image (-1)."""
    prog = _program()
    target = np.zeros((50, 50), dtype=bool)
    target[5:30, 10:40] = True
    canvas = Canvas(3, 50, 50, VP, pyramid=True)
    fm = FeatureMaker(prog, VP, target, context=True)
    turtle = np.array(
        [[0.0, -10.0, math.nan, 1.0], [0.0, -10.0, math.inf, 1.0], [0.0, -10.0, 90.0, 1.0]]
    )
    rows = fm.features(
        prog.sites[1],
        canvas,
        np.arange(3),
        turtle,
        np.zeros(3),
        np.zeros((3, 0)),
        np.full((3, 3), 1 / 3),
    )
    ahead = rows[:, fm.layout(prog.sites[1])["context"]][:, 2:]
    assert (ahead[:2] == -1).all() and (ahead[2] >= 0).all()


@pytest.mark.parametrize("context", [False, True])
def test_memo_gives_the_rows_without_it(context: bool) -> None:
    """kernels.feature_windows with a memo (one step's rounds): rows of a particle at a
    turtle seen before (other depth, width and extra columns) are bit for bit the rows
    made without it; a new turtle (x, y or heading), another particle or a NaN position
    is worked out again."""
    from ngpm_runtime import kernels

    rng = np.random.default_rng(5)
    prog = _program()
    target = np.zeros((50, 50), dtype=bool)
    target[8:40, 12:35] = True
    canvas = Canvas(4, 50, 50, VP)
    for _ in range(6):
        canvas.draw(
            np.arange(4),
            [("disk", rng.uniform(-12, 12), rng.uniform(-22, 2), 2.0) for _ in range(4)],
        )
    fm = FeatureMaker(prog, VP, target, context=context)
    base = np.array([[1.0, -8.0, 30.0, 0.5], [-5.0, -3.0, 200.0, 0.4], [np.nan, -3.0, 10.0, 1.0]])
    turtle = np.concatenate([base, base, base], axis=0)
    turtle[4, 2] += 90.0  # the same place, another heading
    turtle[7, 0] += 3.0  # another x
    idx = np.array([0, 1, 2, 0, 1, 2, 3, 0, 1])
    depth = rng.integers(0, 40, 9).astype(float)
    turtle[:, 3] = rng.uniform(0.1, 1, 9)
    n_extra = np.array([1, 2, 0, 2, 1, 0, 1, 2, 2])
    extra = rng.normal(size=(9, 2))
    width = fm.n_common + 2 + 5  # wider than any row: the columns past it as without a memo
    args = fm.window_args(canvas)

    def rows(memo: np.ndarray, key: np.ndarray) -> np.ndarray:
        out = np.full((9, width), 7.0, dtype=np.float32)
        kernels.feature_windows(out, turtle, depth, idx, *args, extra, n_extra, memo, key)
        return out

    want = rows(kernels.NO_MEMO, kernels.NO_MEMO_KEY)
    memo = np.empty((4, width), dtype=np.float32)
    key = np.full((4, 3), np.nan)
    np.testing.assert_array_equal(rows(memo, key), want)
    # what it kept: each particle's last turtle
    np.testing.assert_array_equal(key[[0, 3], :3], turtle[[7, 6], :3])
    assert np.isnan(key[1, 0]) and np.isnan(key[2, 0])
    np.testing.assert_array_equal(rows(memo, key), want)  # again, with what it kept
