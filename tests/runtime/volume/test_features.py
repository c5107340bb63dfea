"""3D guide features (volume/features.py): the compiled rows against the numpy reference
(windows of the target's and the canvas's pyramids from scratch), for both windows, with
and without a target or a canvas; the cached rows equal fresh ones; the layout."""

from __future__ import annotations

import numpy as np
import pytest
from fixtures.volume3d import GRID, ball_target, random_prim3
from ngpm_runtime.program import Program, Site
from ngpm_runtime.volume.features import WINDOWS, FeatureMaker3D, layout3d, window_of
from ngpm_runtime.volume.raster import VoxelCanvas
from reference import volume as ref

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")
SITE = Site(index=0, id="A/0/normal0", kind="normal", module="A", arity=2)
PROGRAM = Program(name="t", sites=[SITE], axiom=lambda ctx: [], productions={}, derivation_length=6)


def _turtles(rng: np.random.Generator, n: int) -> list[tuple]:
    """3D turtle tuples: mostly in the grid, some outside it or not finite."""
    top = np.array(GRID.lo) + GRID.extent()
    out = []
    for _ in range(n):
        pos = rng.uniform(np.array(GRID.lo) - 1.5, top + 1.5)
        if rng.random() < 0.1:
            pos[rng.integers(3)] = rng.choice([np.nan, np.inf, -np.inf, 1e300])
        frame = np.linalg.qr(rng.normal(size=(3, 3)))[0].T.reshape(-1)
        out.append((*pos, *frame, float(rng.uniform(0.1, 3)), 0, None))
    return out


@pytest.mark.parametrize("window", list(WINDOWS))
@pytest.mark.parametrize(
    ("with_target", "with_canvas"), [(True, True), (False, True), (True, False)]
)
def test_rows_match_the_reference(window: str, with_target: bool, with_canvas: bool) -> None:
    rng = np.random.default_rng(len(window) + 2 * with_target + with_canvas)
    target = ball_target(GRID, (-1.0, 2.5, -0.5), 2.2) if with_target else None
    fm = FeatureMaker3D(PROGRAM, GRID, target, window=window)
    n = 6
    canvas = VoxelCanvas(n, GRID) if with_canvas else None
    if canvas is not None:
        for _ in range(8):
            canvas.draw(np.arange(n), [random_prim3(rng) for _ in range(n)])
    turtles = _turtles(rng, n)
    depths = rng.integers(0, 6, size=n).astype(float)
    params, args = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    got = fm.features(SITE, canvas, np.arange(n), turtles, depths, params, args)
    want = ref.feature_rows(
        fm,
        None if canvas is None else canvas.voxels,
        turtles,
        depths,
        None if target is None else target.occupancy,
    )
    lay = fm.layout(SITE)
    assert got.shape == (n, fm.n_features(SITE)) and lay["partial"].stop == got.shape[1]
    np.testing.assert_array_equal(got[:, :14], want[:, :14])
    np.testing.assert_array_equal(got[:, 14:16], params.astype(np.float32))
    np.testing.assert_array_equal(got[:, 16:18], args.astype(np.float32))
    np.testing.assert_array_equal(got[:, lay["target"]], want[:, 14 : 14 + fm.n_window])
    np.testing.assert_array_equal(got[:, lay["partial"]], want[:, 14 + fm.n_window :])
    if with_canvas:  # the canvas windows saw drawn voxels
        assert (got[:, lay["partial"]] > 0).any()


def test_window_sizes_and_cached_rows() -> None:
    target = ball_target(GRID, (0.0, 2.0, -0.5), 2.0)
    cube = FeatureMaker3D(PROGRAM, GRID, target)
    cross = FeatureMaker3D(PROGRAM, GRID, target, window="cross")
    assert (cube.n_window, cross.n_window) == (2 * 27 * 4 // 2, 7 * 4)
    assert cube.n_features(SITE) == 14 + 2 + 2 + 216
    rng = np.random.default_rng(5)
    canvas = VoxelCanvas(5, GRID)
    canvas.draw(np.arange(5), [random_prim3(rng) for _ in range(5)])
    turtles = _turtles(rng, 5)
    args = [rng.normal(size=(2, 2)), rng.normal(size=(3, 2))]
    pars = [rng.normal(size=(2, 2)), rng.normal(size=(3, 2))]
    idx = [4, 0, 1, 3, 2]
    for depths in ([1.0, 2.0, 3.0, 4.0, 5.0], [0.0, 0.0, 2.0, 2.0, 1.0]):  # the second: cached
        rows = cube.features_cached([SITE, SITE], canvas, idx, turtles, depths, pars, args)
        for j, (lo, hi) in enumerate(((0, 2), (2, 5))):
            fresh = cube.features(
                SITE,
                canvas,
                np.array(idx[lo:hi]),
                turtles[lo:hi],
                np.array(depths[lo:hi]),
                pars[j],
                args[j],
            )
            np.testing.assert_array_equal(rows[j], fresh)
    with pytest.raises(ValueError, match="unknown window"):
        FeatureMaker3D(PROGRAM, GRID, None, window="sphere")


def test_rows_from_equal_features_round_per_site() -> None:
    """rows_from (what SMC's rounds call, with the parameters and prior arguments already
    fitted to each site: a site of arity 0 with 1 argument next to one of arity 2 with 2)
    gives, in each site's columns, the rows features_round gives."""
    rng = np.random.default_rng(9)
    other = Site(index=1, id="B/0/bernoulli0", kind="bernoulli", module="B", arity=0)
    fm = FeatureMaker3D(PROGRAM, GRID, ball_target(GRID, (0.0, 2.0, 0.0), 2.0))
    n = 7
    canvas = VoxelCanvas(n, GRID)
    for _ in range(5):
        canvas.draw(np.arange(n), [random_prim3(rng) for _ in range(n)])
    turtles = _turtles(rng, n)
    depths = rng.integers(0, 6, size=n).astype(float)
    idx = rng.permutation(n)
    params = [rng.normal(size=(4, 2)), np.zeros((3, 0))]
    args = [rng.normal(size=(4, 2)), rng.random(size=(3, 1))]
    want = fm.features_round([SITE, other], canvas, idx.tolist(), turtles, depths, params, args)
    extra = np.zeros((n, 4))
    extra[:4] = np.hstack([params[0], args[0]])
    extra[4:, :1] = args[1]
    n_extra = np.array([4] * 4 + [1] * 3)
    rows = np.array([t[:13] for t in turtles])
    got = fm.rows_from(canvas, idx, rows, depths, extra, n_extra)
    np.testing.assert_array_equal(got[:4, : fm.n_features(SITE)], want[0])
    np.testing.assert_array_equal(got[4:, : fm.n_features(other)], want[1])


@pytest.mark.parametrize(
    "frame", [((1, 0, 0), (0, 1, 0), (0, 0, 1)), ((0, 0, 1), (1, 0, 0), (0, 1, 0))]
)
def test_frame_windows_turn_with_the_turtle(frame: tuple) -> None:
    """A "frame" window's cell (a, b, c) is the grid cell a H + b L + c U away: with the
    turtle's frame on the grid's axes (in any order) it is a "cube" cell, permuted."""
    rng = np.random.default_rng(3)
    target = ball_target(GRID, (0.0, 2.0, -0.5), 2.0)
    canvas = VoxelCanvas(4, GRID)
    for _ in range(6):
        canvas.draw(np.arange(4), [random_prim3(rng) for _ in range(4)])
    lo, top = np.array(GRID.lo), np.array(GRID.lo) + GRID.extent()
    turtles = [
        (*rng.uniform(lo + 0.2 * (top - lo), top - 0.2 * (top - lo)), *np.ravel(frame), 1.0)
        for _ in range(4)
    ]
    h, l_, u = (np.array(v) for v in frame)
    args = (SITE, canvas, np.arange(4), turtles, np.zeros(4), np.zeros((4, 2)), np.zeros((4, 2)))
    cube = FeatureMaker3D(PROGRAM, GRID, target, window="cube").features(*args)
    turned = FeatureMaker3D(PROGRAM, GRID, target, window="frame").features(*args)
    offs = [tuple(o) for o in WINDOWS["cube"].tolist()]
    at = [offs.index(tuple(a * h + b * l_ + c * u)) for a, b, c in offs]
    for group in ("target", "partial"):
        sl = layout3d(SITE, "cube")[group]
        for lv in range(4):
            base = sl.start + 27 * lv
            np.testing.assert_array_equal(
                turned[:, base : base + 27], cube[:, [base + q for q in at]]
            )
    assert layout3d(SITE, "frame")["frame"] == slice(sl.stop, sl.stop)
    assert "frame" not in layout3d(SITE, "cube")


def test_the_window_of_stored_layouts() -> None:
    """Layouts with the empty `frame` group are a frame window's; without it, the cube's
    (every guide made before frame windows)."""
    frame = {"0": {"local": [0, 18], "target": [18, 126], "partial": [126, 234]}}
    assert window_of(frame) == "cube"
    frame["0"]["frame"] = [234, 234]
    assert window_of(frame) == "frame"
    assert window_of({}) == "cube"
