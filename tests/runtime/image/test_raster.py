"""Canvas rasterization against a slow per-pixel transcription of the geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ngpm_runtime.image.raster import Canvas, prim_mask, pyramid, rasterize, viewport_of

VP = (-12.0, 12.0, -22.0, 2.0)


def _inside(prim: tuple, x: float, y: float) -> bool:
    kind = prim[0]
    if kind == "seg":
        _, ax, ay, bx, by, w = prim
        ex, ey = bx - ax, by - ay
        l2 = ex * ex + ey * ey
        t = 0.0 if l2 == 0 else min(1.0, max(0.0, ((x - ax) * ex + (y - ay) * ey) / l2))
        return math.hypot(x - ax - t * ex, y - ay - t * ey) < w / 2
    if kind == "disk":
        _, cx, cy, r = prim
        return math.hypot(x - cx, y - cy) < r
    if kind == "leaf":
        _, bx, by, h, length, width = prim
        c, s = math.cos(math.radians(h)), math.sin(math.radians(h))
        cx, cy = bx + c * length / 2, by + s * length / 2
        u = (x - cx) * c + (y - cy) * s
        v = -(x - cx) * s + (y - cy) * c
        return (u / (length / 2)) ** 2 + (v / (width / 2)) ** 2 < 1
    if kind == "poly":
        verts = prim[1]
        inside = False
        for i in range(len(verts)):
            (xi, yi), (xj, yj) = verts[i], verts[i - 1]
            if (yi > y) != (yj > y) and x < xi + (y - yi) * (xj - xi) / (yj - yi):
                inside = not inside
        return inside
    raise ValueError(kind)


def _slow_image(prims: list[tuple], vp: tuple, h: int, w: int) -> np.ndarray:
    xmin, xmax, ymin, ymax = vp
    img = np.zeros((h, w), dtype=np.uint8)
    for r in range(h):
        y = ymax - (r + 0.5) * (ymax - ymin) / h
        for c in range(w):
            x = xmin + (c + 0.5) * (xmax - xmin) / w
            img[r, c] = any(_inside(p, x, y) for p in prims)
    return img


def _random_prim(rng: np.random.Generator, kinds=("seg", "leaf", "disk", "poly")) -> tuple:
    kind = kinds[rng.integers(len(kinds))]
    x, y = rng.uniform(-15, 15), rng.uniform(-25, 5)
    if kind == "seg":
        a = rng.uniform(0, 2 * math.pi)
        ln = rng.uniform(0, 4)
        return ("seg", x, y, x + ln * math.cos(a), y + ln * math.sin(a), rng.uniform(0.1, 1.5))
    if kind == "leaf":
        return ("leaf", x, y, rng.uniform(-360, 360), rng.uniform(0.5, 3), rng.uniform(0.3, 1.5))
    if kind == "disk":
        return ("disk", x, y, rng.uniform(0.1, 2))
    m = int(rng.integers(3, 7))
    pts = tuple((x + rng.uniform(-3, 3), y + rng.uniform(-3, 3)) for _ in range(m))
    return ("poly", pts)


@pytest.mark.parametrize("size", [(50, 50), (37, 23)])
def test_canvas_matches_slow_rasterization(size: tuple[int, int]) -> None:
    h, w = size
    rng = np.random.default_rng(1)
    n = 6
    canvas = Canvas(n, h, w, VP)
    drawn: list[list[tuple]] = [[] for _ in range(n)]
    for _ in range(12):
        idx = rng.choice(n, size=int(rng.integers(1, n + 1)), replace=False)
        prims = [_random_prim(rng) for _ in idx]
        before = canvas.image.copy()
        batch = canvas.draw(idx, prims)
        ky, kx = batch.new.shape[1:]
        for k, i in enumerate(idx):
            drawn[i].append(prims[k])
            y0, x0 = batch.y0[k], batch.x0[k]
            assert 0 <= y0 and y0 + ky <= h and 0 <= x0 and x0 + kx <= w
            full_new = np.zeros((h, w), dtype=bool)
            full_new[y0 : y0 + ky, x0 : x0 + kx] = batch.new[k]
            expect_new = (canvas.image[i] == 1) & (before[i] == 0)
            assert np.array_equal(full_new, expect_new)
        untouched = np.setdiff1d(np.arange(n), idx)
        assert np.array_equal(canvas.image[untouched], before[untouched])
    for i in range(n):
        assert np.array_equal(canvas.image[i], _slow_image(drawn[i], VP, h, w))
    for got, want in zip(canvas.levels, pyramid(canvas.image), strict=True):
        np.testing.assert_allclose(got, want, atol=1e-5)


def test_bbox_and_outside_primitives() -> None:
    canvas = Canvas(2, 50, 50, VP)
    prims = [("disk", 100.0, 100.0, 1.0), ("seg", 0.0, 0.0, 0.0, 1.0, 0.5)]
    batch = canvas.draw(np.array([0, 1]), prims)
    assert not batch.new[0].any()
    assert canvas.image[0].sum() == 0
    np.testing.assert_allclose(batch.bbox[0], [99, 99, 101, 101])
    np.testing.assert_allclose(batch.bbox[1], [-0.25, -0.25, 0.25, 1.25])
    assert batch.new[1].sum() == canvas.image[1].sum() > 0


def test_pixel_convention_row0_at_ymax() -> None:
    # a small disk at the top-left pixel center
    vp = (0.0, 10.0, 0.0, 10.0)
    img = rasterize([("disk", 0.5, 9.5, 0.2)], vp, 10, 10)
    assert img[0, 0] == 1 and img.sum() == 1
    # center exactly on the boundary is not covered (strict inside)
    assert rasterize([("disk", 0.5, 9.5, 1.0)], vp, 10, 10).sum() == 1


def test_redraw_gives_no_new_pixels_and_take_reindexes() -> None:
    canvas = Canvas(3, 40, 40, VP)
    canvas.draw([0, 1, 2], [("disk", 0, -10, 2), ("disk", 5, -5, 1), ("disk", -5, -15, 3)])
    batch = canvas.draw([0], [("disk", 0, -10, 1.5)])
    assert not batch.new.any()
    imgs = canvas.image.copy()
    lv2 = canvas.levels[2].copy()
    canvas.take(np.array([2, 2, 0, 1]))
    assert canvas.image.shape == (4, 40, 40) and canvas.n == 4
    assert np.array_equal(canvas.image, imgs[[2, 2, 0, 1]])
    assert canvas.levels[0] is canvas.image
    np.testing.assert_array_equal(canvas.levels[2], lv2[[2, 2, 0, 1]])
    # the copies are independent after take
    canvas.draw([0], [("disk", 10, 0, 1)])
    assert not np.array_equal(canvas.image[0], canvas.image[1])


def test_prim_mask_and_viewport_of() -> None:
    prim = ("leaf", 0.0, -10.0, 30.0, 3.0, 1.0)
    y0, x0, m = prim_mask(prim, VP, 50, 50)
    full = np.zeros((50, 50), dtype=np.uint8)
    full[y0 : y0 + m.shape[0], x0 : x0 + m.shape[1]] = m
    assert np.array_equal(full, _slow_image([prim], VP, 50, 50))
    vp = viewport_of([("seg", 0, 0, 4, 0, 1), ("disk", 0, 3, 1)])
    assert vp[0] < -0.5 and vp[1] > 4.5 and vp[2] < -0.5 and vp[3] > 4
    assert math.isclose(vp[1] - vp[0], vp[3] - vp[2])


def test_repeated_take_with_double_buffers() -> None:
    rng = np.random.default_rng(7)
    n = 5
    canvas = Canvas(n, 30, 30, VP)
    ref_img = np.zeros((n, 30, 30), dtype=np.uint8)
    for _ in range(6):
        prims = [
            ("disk", rng.uniform(-12, 12), rng.uniform(-22, 2), rng.uniform(0.5, 3))
            for _ in range(n)
        ]
        canvas.draw(np.arange(n), prims)
        for i, p in enumerate(prims):
            ref_img[i] |= rasterize([p], VP, 30, 30)
        anc = np.sort(rng.integers(0, n, n))
        canvas.take(anc)
        ref_img = ref_img[anc]
        assert np.array_equal(canvas.image, ref_img)
        assert canvas.levels[0] is canvas.image
        for got, want in zip(canvas.levels, pyramid(ref_img), strict=True):
            np.testing.assert_allclose(got, want, atol=1e-5)


def test_degenerate_primitives() -> None:
    # a zero-length segment is a disk of radius width / 2 (round caps)
    seg = rasterize([("seg", 0.3, -9.7, 0.3, -9.7, 4.0)], VP, 50, 50)
    disk = rasterize([("disk", 0.3, -9.7, 2.0)], VP, 50, 50)
    assert seg.sum() > 0 and np.array_equal(seg, disk)
    canvas = Canvas(4, 50, 50, VP)
    prims = [
        ("leaf", 0.0, -10.0, 30.0, 3.0, 0.0),
        ("disk", float("nan"), 0.0, 1.0),
        ("seg", 0.0, 0.0, float("inf"), 0.0, 1.0),
        ("poly", ((0.0, 0.0), (1.0, 1.0))),
    ]
    batch = canvas.draw(np.arange(4), prims)
    assert not batch.new.any() and canvas.image.sum() == 0
    assert all(lv.sum() == 0 for lv in canvas.levels)


def test_bbox_of_matches_draw_boxes() -> None:
    from ngpm_runtime.image.raster import bbox_of

    rng = np.random.default_rng(11)
    prims = [_random_prim(rng) for _ in range(20)]
    canvas = Canvas(20, 20, 20, VP)
    b = canvas.draw(np.arange(20), prims).bbox
    want = np.concatenate([b[:, :2].min(axis=0), b[:, 2:].max(axis=0)])
    np.testing.assert_allclose(bbox_of(prims), want)
    assert np.isinf(bbox_of([])).all()


def _prim_strategy():
    from hypothesis import strategies as st

    coord = st.floats(-16, 16, allow_nan=False)
    pos = st.floats(0.05, 4)
    return st.one_of(
        st.tuples(st.just("seg"), coord, coord, coord, coord, pos),
        st.tuples(st.just("leaf"), coord, coord, st.floats(-720, 720), pos, pos),
        st.tuples(st.just("disk"), coord, coord, pos),
        st.tuples(
            st.just("poly"), st.lists(st.tuples(coord, coord), min_size=3, max_size=6).map(tuple)
        ),
    )


def test_property_batched_draw_equals_slow_rasterization() -> None:
    from hypothesis import given, settings
    from hypothesis import strategies as st

    vp = (-8.0, 8.0, -6.0, 6.0)

    @settings(max_examples=60, deadline=None, derandomize=True)
    @given(st.lists(_prim_strategy(), min_size=1, max_size=5))
    def check(prims: list[tuple]) -> None:
        canvas = Canvas(len(prims), 12, 16, vp)
        canvas.draw(np.arange(len(prims)), prims)
        for k, p in enumerate(prims):
            assert np.array_equal(canvas.image[k], _slow_image([p], vp, 12, 16))

    check()


def test_mixed_kinds_without_polygons_draw_as_one_by_one() -> None:
    """A batch of segments, leaves and disks (packed for the kernel through one flat list)
    draws what drawing each primitive alone draws; a primitive of an unknown kind or with
    too many parameters is a ValueError."""
    rng = np.random.default_rng(7)
    prims = [_random_prim(rng, ("seg", "leaf", "disk")) for _ in range(40)]
    assert {p[0] for p in prims} == {"seg", "leaf", "disk"}
    canvas = Canvas(len(prims), 50, 50, VP)
    batch = canvas.draw(np.arange(len(prims)), prims)
    for k, p in enumerate(prims):
        one = Canvas(1, 50, 50, VP)
        alone = one.draw(np.zeros(1, dtype=np.intp), [p])
        assert np.array_equal(canvas.image[k], one.image[0])
        assert np.array_equal(batch.bbox[k], alone.bbox[0])
    with pytest.raises(ValueError, match="unknown primitive kind 'blob'"):
        canvas.draw(np.arange(2), [prims[0], ("blob", 1.0)])
    with pytest.raises(ValueError, match="more than 5 parameters"):
        canvas.draw(np.arange(2), [("disk", 0.0, 0.0, 1.0), ("seg", 0.0, 0.0, 1.0, 1.0, 1.0, 9.0)])
