"""The numpy resampling the compiled residual kernel replaced (ngpm_runtime/kernels.py),
kept as the tests' reference: every scheme as the runtime's before numba (git history:
runtime/ngpm_runtime/inference/resample.py)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def _cumulative(w: np.ndarray) -> np.ndarray:
    cum = np.cumsum(w)
    cum /= cum[-1]
    cum[-1] = 1.0
    return cum


def _search(cum: np.ndarray, u: np.ndarray) -> np.ndarray:
    # side="right": u in [cum[i-1], cum[i]) picks i, so zero-weight particles never win
    return np.minimum(np.searchsorted(cum, u, side="right"), len(cum) - 1)


def multinomial(w: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return np.sort(_search(_cumulative(w), rng.random(n)))


def stratified(w: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return _search(_cumulative(w), (np.arange(n) + rng.random(n)) / n)


def systematic(w: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return _search(_cumulative(w), (np.arange(n) + rng.random()) / n)


def residual(w: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    w = w / w.sum()
    scaled = n * w
    counts = np.floor(scaled).astype(np.int64)
    rest = n - int(counts.sum())
    if rest > 0:
        frac = scaled - counts
        extra = _search(_cumulative(frac), rng.random(rest))
        counts += np.bincount(extra, minlength=len(w))
    return np.repeat(np.arange(len(w)), counts)


SCHEMES: dict[str, Callable[[np.ndarray, int, np.random.Generator], np.ndarray]] = {
    "multinomial": multinomial,
    "stratified": stratified,
    "systematic": systematic,
    "residual": residual,
}


def resample(
    scheme: str, log_w: np.ndarray, rng: np.random.Generator, n: int | None = None
) -> np.ndarray:
    """Ancestor indices (ascending) drawn with `scheme` from unnormalized log weights."""
    w = np.exp(log_w - np.max(log_w))
    return SCHEMES[scheme](w, len(log_w) if n is None else n, rng)
