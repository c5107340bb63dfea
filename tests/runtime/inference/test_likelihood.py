"""Likelihoods: incremental sums equal from-scratch values; formulas match a slow transcription."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ngpm_runtime.errors import TargetError
from ngpm_runtime.image.raster import Canvas
from ngpm_runtime.inference.likelihood import (
    CIRCUIT_SIGMA,
    CircuitLikelihood,
    NullLikelihood,
    ShapeLikelihood,
    bounds_penalty,
    circuit_loglik,
    circuit_score,
    shape_loglik,
    similarity,
    sobel,
)

VP = (-12.0, 12.0, -22.0, 2.0)
KX = [[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]]


def _slow_sobel(img: np.ndarray) -> np.ndarray:
    h, w = img.shape
    out = np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            gx = gy = 0.0
            for i in range(3):
                for j in range(3):
                    rr, cc = r + i - 1, c + j - 1
                    v = float(img[rr, cc]) if 0 <= rr < h and 0 <= cc < w else 0.0
                    gx += KX[i][j] * v
                    gy += KX[j][i] * v
            out[r, c] = math.sqrt(gx * gx + gy * gy) / 4.0
    return out


def _slow_overhang(bbox, vp) -> float:
    xmin, xmax, ymin, ymax = vp
    ex = (max(0.0, xmin - bbox[0]) + max(0.0, bbox[2] - xmax)) / (xmax - xmin)
    ey = (max(0.0, ymin - bbox[1]) + max(0.0, bbox[3] - ymax)) / (ymax - ymin)
    return -((ex / 0.001) ** 2) - (ey / 0.001) ** 2


def _slow_shape(img: np.ndarray, t: np.ndarray, bbox, vp) -> float:
    edges = _slow_sobel(t.astype(float))
    num = den = blank = 0.0
    for r in range(t.shape[0]):
        for c in range(t.shape[1]):
            w = 1.0 if not t[r, c] else 1 / 1.5 + (1 - 1 / 1.5) * min(1.0, edges[r, c])
            den += w
            num += w * (bool(img[r, c]) == bool(t[r, c]))
            blank += w * (not t[r, c])
    sim, sim0 = num / den, blank / den
    s = (sim - sim0) / (1 - sim0)
    return -((s - 1) ** 2) / 0.02**2 + _slow_overhang(bbox, vp)


def _slow_circuit(img: np.ndarray, bbox, vp) -> float:
    edge = _slow_sobel(img.astype(float)).mean()
    fill = img.astype(float).mean()
    x = edge * (1 - abs(fill - 0.5) / 0.5)
    return (
        -0.5 * ((x - 1) / 0.01) ** 2
        - math.log(0.01 * math.sqrt(2 * math.pi))
        + _slow_overhang(bbox, vp)
    )


def _hand_images() -> tuple[np.ndarray, np.ndarray]:
    t = np.zeros((12, 10), dtype=bool)
    t[2:9, 3:7] = True
    t[0, 0] = True  # a border pixel: zero padding makes it an edge
    img = np.zeros((12, 10), dtype=np.uint8)
    img[4:11, 2:5] = 1
    img[0, 9] = 1
    return t, img


def test_sobel_matches_slow_kernels() -> None:
    t, img = _hand_images()
    np.testing.assert_allclose(sobel(t), _slow_sobel(t.astype(float)))
    np.testing.assert_allclose(sobel(img), _slow_sobel(img.astype(float)))
    # a straight vertical edge inside the image reads exactly 1
    half = np.zeros((6, 6))
    half[:, :3] = 1
    assert sobel(half)[2, 2] == pytest.approx(1.0)


def test_shape_formula_on_hand_made_images() -> None:
    t, img = _hand_images()
    bbox = np.array([-13.0, -21.0, 11.0, 2.5])
    assert shape_loglik(img, t, bbox, VP) == pytest.approx(_slow_shape(img, t, bbox, VP))
    assert similarity(t.astype(np.uint8), t) == pytest.approx(1.0)
    assert similarity(np.zeros_like(img), t) == pytest.approx(0.0)
    assert similarity(img, t) < 1.0


def test_circuit_formula_on_hand_made_images() -> None:
    _, img = _hand_images()
    bbox = np.array([-11.0, -23.0, 11.0, 1.0])
    assert circuit_loglik(img, bbox, VP) == pytest.approx(_slow_circuit(img, bbox, VP))


def test_bounds_penalty() -> None:
    assert bounds_penalty(np.array([-12.0, -22.0, 12.0, 2.0]), VP) == 0.0
    b = np.array([-12.024, -22.0, 12.0, 2.048])
    assert bounds_penalty(b, VP) == pytest.approx(-1.0 - 4.0)
    assert bounds_penalty(np.array([np.inf, np.inf, -np.inf, -np.inf]), VP) == 0.0


def _random_prims(rng: np.random.Generator, n: int) -> list[tuple]:
    out = []
    for _ in range(n):
        x, y = rng.uniform(-14, 14), rng.uniform(-24, 4)
        k = rng.integers(3)
        if k == 0:
            a = rng.uniform(0, 2 * math.pi)
            out.append(
                ("seg", x, y, x + 2 * math.cos(a), y + 2 * math.sin(a), rng.uniform(0.2, 1.2))
            )
        elif k == 1:
            out.append(("leaf", x, y, rng.uniform(0, 360), 2.0, 1.0))
        else:
            out.append(("disk", x, y, rng.uniform(0.3, 1.5)))
    return out


@pytest.mark.parametrize("kind", ["shape", "circuit"])
def test_increments_telescope_to_full_value(kind: str) -> None:
    rng = np.random.default_rng(3)
    h, w = 30, 30
    t = np.zeros((h, w), dtype=bool)
    t[5:25, 10:20] = True
    lik = ShapeLikelihood(t, VP) if kind == "shape" else CircuitLikelihood(VP)
    n = 5
    canvas = Canvas(n, h, w, VP)
    state = lik.start(n)
    total = np.zeros(n)
    boxes = np.tile([np.inf, np.inf, -np.inf, -np.inf], (n, 1))
    for step in range(40):
        idx = rng.choice(n, size=int(rng.integers(1, n + 1)), replace=False)
        batch = canvas.draw(idx, _random_prims(rng, len(idx)))
        total[idx] += lik.increment(state, canvas, batch)
        boxes[idx, :2] = np.minimum(boxes[idx, :2], batch.bbox[:, :2])
        boxes[idx, 2:] = np.maximum(boxes[idx, 2:], batch.bbox[:, 2:])
        if step == 20:  # resampling reindexes state and canvas together
            perm = rng.integers(0, n, size=n)
            perm[:2] = [0, 1]
            canvas.take(perm)
            state = {k: v[perm] for k, v in state.items()}
            total, boxes = total[perm], boxes[perm]
    # the circuit's increments follow its potential; settling adds the rest, once
    total += lik.settle(state, np.arange(n))
    assert not lik.settle(state, np.arange(n)).any()
    assert lik.settles == (kind == "circuit")
    for i in range(n):
        if not np.isfinite(boxes[i]).all():
            continue
        want = (
            _slow_shape(canvas.image[i], t, boxes[i], VP)
            if kind == "shape"
            else _slow_circuit(canvas.image[i], boxes[i], VP)
        )
        assert total[i] == pytest.approx(want, rel=1e-9, abs=1e-6)
        assert lik.full(canvas.image[i], boxes[i]) == pytest.approx(want, rel=1e-9, abs=1e-6)


def test_null_and_empty_target() -> None:
    canvas = Canvas(2, 10, 10, VP)
    batch = canvas.draw([1], [("disk", 0, -10, 3)])
    null = NullLikelihood()
    assert np.array_equal(null.increment(null.start(2), canvas, batch), [0.0])
    with pytest.raises(TargetError):
        ShapeLikelihood(np.zeros((10, 10), dtype=bool), VP)


def test_drawbatch_without_hit_list_gives_same_increments() -> None:
    from ngpm_runtime.image.raster import DrawBatch

    t = np.zeros((30, 30), dtype=bool)
    t[5:25, 10:20] = True
    rng = np.random.default_rng(5)
    canvas = Canvas(4, 30, 30, VP)
    lik = ShapeLikelihood(t, VP)
    s1, s2 = lik.start(4), lik.start(4)
    for _ in range(10):
        b = canvas.draw(np.arange(4), _random_prims(rng, 4))
        bare = DrawBatch(idx=b.idx, y0=b.y0, x0=b.x0, new=b.new, bbox=b.bbox)
        np.testing.assert_allclose(lik.increment(s1, canvas, b), lik.increment(s2, canvas, bare))


def test_circuit_score_is_equation_2s_argument() -> None:
    assert circuit_score(np.zeros((20, 20))) == 0.0
    half = np.zeros((20, 20))
    half[:, :10] = 1
    stripes = np.zeros((20, 20))
    stripes[:, ::4] = stripes[:, 1::4] = 1  # half filled, edges everywhere
    assert 0 < circuit_score(half) < circuit_score(stripes)
    # the log-likelihood is the Gaussian of the score around 1 (without bounds terms)
    inside = np.array([-1.0, -1.0, 1.0, 1.0])  # a box inside the viewport
    x = circuit_score(stripes)
    want = -0.5 * ((x - 1) / CIRCUIT_SIGMA) ** 2 - np.log(CIRCUIT_SIGMA * np.sqrt(2 * np.pi))
    assert circuit_loglik(stripes, inside, VP) == pytest.approx(want)
