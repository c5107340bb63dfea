"""Binary-image helpers for automatic start poses, in plain numpy.

These reproduce, bit for bit, what the runtime used from SciPy and scikit-image, so the
runtime installs without either (tests/runtime/image/test_morphology.py compares them on
random and real shapes):

- `otsu_threshold`: skimage.filters.threshold_otsu on integer images
- `label`: skimage.measure.label(mask, connectivity=2) (labels in raster order of first pixel)
- `skeletonize`: skimage.morphology.skeletonize (Zhang-Suen thinning, two parallel sub-passes)
- `max_edt`: scipy.ndimage.distance_transform_edt(mask).max()
- `neighbor_count`: scipy.ndimage.convolve with a 3x3 ring of ones, mode="constant"
"""

from __future__ import annotations

import math

import numpy as np


def otsu_threshold(image: np.ndarray) -> int:
    """Otsu's threshold of an integer image: pixels <= it are the dark class."""
    flat = np.asarray(image).reshape(-1)
    if np.all(flat == flat[0]):
        return int(flat[0])
    lo, hi = int(flat.min()), int(flat.max())
    counts = np.bincount((flat.astype(np.int64) - lo), minlength=hi - lo + 1)
    counts = counts.astype(np.float32)
    centers = np.arange(lo, hi + 1)
    weight1 = np.cumsum(counts)
    weight2 = np.cumsum(counts[::-1])[::-1]
    mean1 = np.cumsum(counts * centers) / weight1
    mean2 = (np.cumsum((counts * centers)[::-1]) / weight2[::-1])[::-1]
    variance12 = weight1[:-1] * weight2[1:] * (mean1[:-1] - mean2[1:]) ** 2
    return int(centers[int(np.argmax(variance12))])


def neighbor_count(mask: np.ndarray) -> np.ndarray:
    """Number of set 8-neighbors of every pixel (outside the image counts as unset)."""
    p = np.pad(np.asarray(mask).astype(np.int32), 1)
    return (
        p[:-2, :-2]
        + p[:-2, 1:-1]
        + p[:-2, 2:]
        + p[1:-1, :-2]
        + p[1:-1, 2:]
        + p[2:, :-2]
        + p[2:, 1:-1]
        + p[2:, 2:]
    )


def label(mask: np.ndarray) -> np.ndarray:
    """8-connected components: 0 = background, 1.. in raster order of each first pixel.

    Union-find over the horizontal runs of each row: a run joins every run of the row
    above that overlaps it or touches it diagonally.
    """
    mask = np.asarray(mask, dtype=bool)
    h, w = mask.shape
    runs: list[tuple[int, int, int]] = []  # (row, start, end exclusive)
    row_runs: list[list[int]] = []
    for r in range(h):
        padded = np.concatenate(([False], mask[r], [False])).astype(np.int8)
        edges = np.flatnonzero(np.diff(padded))
        ids = []
        for s, e in zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True):
            ids.append(len(runs))
            runs.append((r, s, e))
        row_runs.append(ids)
    parent = list(range(len(runs)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for r in range(1, h):
        above = row_runs[r - 1]
        for i in row_runs[r]:
            _, s, e = runs[i]
            for j in above:
                _, s2, e2 = runs[j]
                if s2 <= e and s <= e2:  # overlapping or diagonal touch (8-connectivity)
                    a, b = find(i), find(j)
                    if a != b:
                        parent[max(a, b)] = min(a, b)
    out = np.zeros((h, w), dtype=np.int64)
    numbers: dict[int, int] = {}
    for i, (r, s, e) in enumerate(runs):  # runs are in raster order: number roots as met
        root = find(i)
        if root not in numbers:
            numbers[root] = len(numbers) + 1
        out[r, s:e] = numbers[root]
    return out


def max_edt(mask: np.ndarray) -> float:
    """Largest Euclidean distance from a set pixel to the nearest unset pixel.

    Exact squared distances (a column pass, then a row pass over all columns), so the
    value equals SciPy's. Without unset pixels SciPy measures to the point just above the
    top-left pixel; so does this.
    """
    mask = np.asarray(mask, dtype=bool)
    h, w = mask.shape
    if not mask.any():
        return 0.0
    if mask.all():
        return math.sqrt(float(h * h + (w - 1) ** 2))
    big = h + w + 1  # larger than any in-image distance
    col = np.where(mask, big, 0).astype(np.int64)  # vertical distance to nearest 0
    for r in range(1, h):
        col[r] = np.minimum(col[r], col[r - 1] + 1)
    for r in range(h - 2, -1, -1):
        col[r] = np.minimum(col[r], col[r + 1] + 1)
    g2 = np.where(col >= big, np.int64(big) ** 2 * 4, col * col)  # (h, w)
    xs = np.arange(w, dtype=np.int64)
    dx2 = (xs[:, None] - xs[None, :]) ** 2  # (w, w)
    best = 0
    step = max(1, 2_000_000 // (w * w))
    for r0 in range(0, h, step):
        block = g2[r0 : r0 + step]  # (b, w)
        d2 = (block[:, None, :] + dx2[None, :, :]).min(axis=2)  # (b, w)
        best = max(best, int(d2.max()))
    return math.sqrt(float(best))


# Removal table: for each 8-neighborhood code (weights 1 NW, 2 N, 4 NE, 8 E, 16 SE, 32 S,
# 64 SW, 128 W) the sub-passes that remove the center pixel (0 none, 1 first, 2 second,
# 3 both). Fitted to scikit-image's skeletonize (coordinate search over the 256 entries on
# thousands of random images until every output matched) and checked against it by
# tests/runtime/image/test_morphology.py.
_ZS_TABLE = np.array(
    [
        int(c)
        for c in (
            "0001001300111013000000002020303300000000300000000000000020003022"
            "0000000000000000000000000000000020000000200020003000000030003020"
            "0031001300000001000000000000000131000000000000002000000000000000"
            "2313001300000001000000000000000023010001000000003301000022002000"
        )
    ],
    dtype=np.uint8,
)


def skeletonize(mask: np.ndarray) -> np.ndarray:
    """Thin a binary mask to a one-pixel-wide skeleton (Zhang-Suen, parallel sub-passes)."""
    table = _ZS_TABLE
    s = np.pad(np.asarray(mask).astype(np.uint8), 1)
    core = s[1:-1, 1:-1]
    removed = True
    while removed:
        removed = False
        for sub in (1, 2):
            code = (
                s[:-2, :-2]
                + 2 * s[:-2, 1:-1]
                + 4 * s[:-2, 2:]
                + 8 * s[1:-1, 2:]
                + 16 * s[2:, 2:]
                + 32 * s[2:, 1:-1]
                + 64 * s[2:, :-2]
                + 128 * s[1:-1, :-2]
            )
            v = table[code]
            kill = (core == 1) & ((v == 3) | (v == sub))
            if kill.any():
                removed = True
                core[kill] = 0
    return core.astype(bool)
