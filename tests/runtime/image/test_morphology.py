"""The runtime's numpy morphology equals SciPy / scikit-image on random and real shapes."""

from __future__ import annotations

import numpy as np
import pytest
from ngpm_runtime.image import morphology as m
from ngpm_runtime.image.targets import auto_start, load_target
from repo_paths import DATA
from scipy.ndimage import convolve, distance_transform_edt
from skimage.filters import threshold_otsu
from skimage.measure import label
from skimage.morphology import skeletonize


def random_masks(seed: int, count: int) -> list[np.ndarray]:
    """Noise, blobs (thresholded smoothed noise) and strokes, of many sizes and densities."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        h, w = int(rng.integers(3, 60)), int(rng.integers(3, 60))
        kind = i % 3
        if kind == 0:
            out.append(rng.random((h, w)) < rng.uniform(0.1, 0.95))
        else:
            noise = rng.random((h + 4, w + 4))
            for _ in range(int(rng.integers(1, 5))):
                noise = (
                    noise[:-2, :-2]
                    + noise[1:-1, 1:-1]
                    + noise[2:, 2:]
                    + noise[:-2, 2:]
                    + noise[2:, :-2]
                ) / 5
                noise = np.pad(noise, 1, mode="edge")
            out.append(noise[2 : h + 2, 2 : w + 2] > np.quantile(noise, rng.uniform(0.2, 0.8)))
    return out


def real_masks() -> list[np.ndarray]:
    masks = [load_target(p, size=None).mask for p in sorted(DATA.glob("demo_*.png"))]
    masks += [load_target(p).mask for p in sorted(DATA.glob("demo_*.png"))]
    from skimage.data import horse

    masks.append(~horse().astype(bool))
    return masks


MASKS = random_masks(0, 600)


@pytest.mark.parametrize("chunk", range(6))
def test_skeletonize_equals_skimage(chunk: int) -> None:
    for mask in MASKS[chunk::6]:
        assert np.array_equal(m.skeletonize(mask), skeletonize(mask))


def test_skeletonize_equals_skimage_on_real_shapes() -> None:
    for mask in real_masks():
        assert np.array_equal(m.skeletonize(mask), skeletonize(mask))


def test_label_equals_skimage() -> None:
    for mask in MASKS + real_masks():
        assert np.array_equal(m.label(mask), label(mask, connectivity=2))


def test_max_edt_equals_scipy() -> None:
    for mask in MASKS + real_masks() + [np.ones((3, 4), bool), np.ones((1, 1), bool)]:
        if mask.any():
            assert m.max_edt(mask) == float(distance_transform_edt(mask).max())


def test_neighbor_count_equals_convolve() -> None:
    kernel = np.ones((3, 3), dtype=np.int32)
    kernel[1, 1] = 0
    for mask in MASKS[:100]:
        want = convolve(mask.astype(np.int32), kernel, mode="constant")
        assert np.array_equal(m.neighbor_count(mask), want)


def test_otsu_equals_skimage() -> None:
    rng = np.random.default_rng(1)
    images = [
        rng.integers(
            lo, hi, size=(int(rng.integers(5, 80)), int(rng.integers(5, 80))), dtype=np.uint8
        )
        for lo, hi in [(0, 256), (0, 3), (100, 140), (250, 256)] * 30
    ]
    images += [
        (np.asarray(mask, np.uint8) * 200 + rng.integers(0, 40, mask.shape)).astype(np.uint8)
        for mask in MASKS[:60]
    ]
    for img in images:
        assert m.otsu_threshold(img) == threshold_otsu(img)


def _auto_start_scipy(mask: np.ndarray) -> tuple[float, ...]:
    """auto_start with the SciPy / scikit-image functions the runtime used before."""
    import ngpm_runtime.image.targets as targets

    saved = {k: getattr(targets, k) for k in ("label", "skeletonize", "max_edt", "neighbor_count")}
    kernel = np.ones((3, 3), dtype=np.int32)
    kernel[1, 1] = 0
    try:
        targets.label = lambda x: label(x, connectivity=2)
        targets.skeletonize = skeletonize
        targets.max_edt = lambda x: float(distance_transform_edt(x).max())
        targets.neighbor_count = lambda x: convolve(x.astype(np.int32), kernel, mode="constant")
        return targets.auto_start(mask)
    finally:
        for k, v in saved.items():
            setattr(targets, k, v)


def test_auto_start_unchanged() -> None:
    for mask in [x for x in MASKS[::3] if x.sum() >= 4] + real_masks():
        assert auto_start(mask) == _auto_start_scipy(mask)
