"""Resampling schemes for SMC. Each returns `n` ancestor indices in ascending order.
The weights and the residual scheme (SMC's default) are compiled (ngpm_runtime.kernels)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

_NO_DRAWS = np.zeros(0)


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


def _residual_draws(
    w: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residual resampling's copies per particle, the fractional parts' cumulative sum and
    the draws for the rest: kernels.ancestors(*these) are the ancestors."""
    from ngpm_runtime import kernels

    counts, cum, rest = kernels.residual_counts(np.ascontiguousarray(w, dtype=np.float64), n)
    return counts, cum, rng.random(rest) if rest > 0 else _NO_DRAWS


def residual(w: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    from ngpm_runtime import kernels

    anc: np.ndarray = kernels.ancestors(*_residual_draws(w, n, rng))
    return anc


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
    from ngpm_runtime import kernels

    w = kernels.weights(np.ascontiguousarray(log_w, dtype=np.float64))
    return SCHEMES[scheme](w, len(log_w) if n is None else n, rng)


def ancestor_counts(
    scheme: str, log_w: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`resample`'s ancestors (n = len(log_w)) as kernels.ancestors' arguments, the same
    draws from rng: the residual scheme's parts, another scheme's ancestors as copies per
    particle (no fractional parts, no draws)."""
    from ngpm_runtime import kernels

    n = len(log_w)
    if scheme == "residual":
        w = kernels.weights(np.ascontiguousarray(log_w, dtype=np.float64))
        return _residual_draws(w, n, rng)
    return np.bincount(resample(scheme, log_w, rng), minlength=n), _NO_DRAWS, _NO_DRAWS
