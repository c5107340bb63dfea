"""Batched densities and samplers for the four site kinds (architecture.md sections 4, 5).

Every function works on `n` particles at once: `args` is `(n, n_args)` float64 (prior
arguments per section 4), `params` is `(n, n_params)` (guide outputs per section 5) and
`values` is `(n,)` float64. Log densities are float64; impossible values give -inf, never NaN.

Guide parameter layouts, `K` mixture components:
- normal: columns `[0:K]` log mixture weights (normalized here), `[K:2K]` means and
  `[2K:3K]` log sds, in prior units: `mean = mu + sigma * m`, `sd = sigma * exp(s)`.
- uniform on `(a, b)`: the same `(n, 3K)` layout for a normal mixture on `z`, and
  `x = a + (b - a) * sigmoid(z)`.
- bernoulli: `(n, 1)` probability of 1; categorical: `(n, k)` probabilities (normalized here).
"""

from __future__ import annotations

import math
from itertools import accumulate

import numpy as np

from ngpm_runtime.errors import ProgramError
from ngpm_runtime.program import Site

LOG_2PI = float(np.log(2.0 * np.pi))
_TINY = 1e-300


def _log(x: np.ndarray) -> np.ndarray:
    """log that maps 0 to -inf without a warning."""
    with np.errstate(divide="ignore"):
        out: np.ndarray = np.log(x)
    return out


def _normal_logpdf(x: np.ndarray, mean: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """Normal log density; sd == 0 is a point mass (log density 0 at the mean)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (x - mean) / sd
        out = -0.5 * z * z - np.log(sd) - 0.5 * LOG_2PI
    point = sd == 0
    if point.any():
        out = np.where(point, np.where(x == mean, 0.0, -np.inf), out)
    return np.where(np.isnan(out), -np.inf, out)


def _categorical_probs(site: Site, w: np.ndarray) -> np.ndarray:
    """Normalize categorical weights row-wise; bad weights are the program's fault."""
    w = np.asarray(w, dtype=np.float64)
    total = w.sum(axis=1, keepdims=True)
    if not np.all(np.isfinite(w)) or (w < 0).any() or (total <= 0).any():
        raise ProgramError(
            f"site {site.id} (line {site.line}): categorical weights must be finite, "
            "non-negative and not all zero"
        )
    out: np.ndarray = w / total
    return out


def _categorical_sample(p: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One draw per row of the probability matrix `p`, by inverting the cumulative sums."""
    cum = np.cumsum(p, axis=1)
    u = rng.random(p.shape[0]) * cum[:, -1]
    idx = (cum <= u[:, None]).sum(axis=1)
    # never land on a zero-probability category through rounding at the top end
    idx = np.minimum(idx, p.shape[1] - 1)
    out: np.ndarray = idx.astype(np.float64)
    return out


def _categorical_logpmf(p: np.ndarray, values: np.ndarray,
                        rows: np.ndarray | None = None) -> np.ndarray:
    """log p[row, value] per value; `rows` picks the row of `p` for each value
    (default: row i for value i)."""
    v = np.asarray(values)
    ok = (v >= 0) & (v < p.shape[1]) & (v == np.floor(v))
    k = np.where(ok, v, 0).astype(np.intp)
    out = _log(p[np.arange(p.shape[0]) if rows is None else rows, k])
    return np.where(ok, out, -np.inf)


def _uniform_bounds(args: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.minimum(args[:, 0], args[:, 1])
    b = np.maximum(args[:, 0], args[:, 1])
    return a, b


def _check_args(site: Site, args: np.ndarray) -> np.ndarray:
    args = np.asarray(args, dtype=np.float64)
    if args.ndim != 2:
        raise ValueError(f"prior args for site {site.id} must be 2-D, got shape {args.shape}")
    if site.kind in ("normal", "uniform", "bernoulli") and not np.all(np.isfinite(args)):
        raise ProgramError(
            f"site {site.id} (line {site.line}): non-finite {site.kind} arguments"
        )
    return args


# --------------------------------------------------------------------------- prior


def prior_draw(
    site: Site, args: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Draw one value per row of `args` from the site's prior; returns (values, log prior)."""
    args = _check_args(site, args)
    n = args.shape[0]
    kind = site.kind
    if kind == "normal":
        z = rng.standard_normal(n)
        sd = np.abs(args[:, 1])
        if (sd > 0).all():
            return args[:, 0] + sd * z, -0.5 * z * z - np.log(sd) - 0.5 * LOG_2PI
        v = args[:, 0] + sd * z
        return v, _normal_logpdf(v, args[:, 0], sd)
    if kind == "uniform":
        a, b = _uniform_bounds(args)
        width = b - a
        v = a + width * rng.random(n)
        return v, -_log(np.where(width > 0, width, 1.0))
    if kind == "bernoulli":
        p = np.clip(args[:, 0], 0.0, 1.0)
        v = (rng.random(n) < p).astype(np.float64)
        return v, _log(np.where(v == 1.0, p, 1.0 - p))
    if kind == "categorical":
        if n > 1 and (args == args[0]).all():  # one distribution for all rows (groups)
            w = args[0].tolist()
            total = math.fsum(w)
            if not (total > 0 and all(0.0 <= x < math.inf for x in w)):
                _categorical_probs(site, args[:1])  # raises the error
            cum = np.array(list(accumulate(w)))
            k = np.minimum(np.searchsorted(cum, rng.random(n) * cum[-1], side="right"),
                           len(w) - 1)
            return k.astype(np.float64), _log(np.array(w) / total)[k]
        p = _categorical_probs(site, args)
        v = _categorical_sample(p, rng)
        return v, _log(p[np.arange(n), v.astype(np.intp)])
    raise ProgramError(f"site {site.id}: unknown kind {kind!r}")


def prior_sample(site: Site, args: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Draw one value per row of `args` from the site's prior."""
    return prior_draw(site, args, rng)[0]


def prior_logpdf(site: Site, args: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Log prior density (or mass) of `values` under the site's prior, shape `(n,)`."""
    args = _check_args(site, args)
    x = np.asarray(values, dtype=np.float64)
    kind = site.kind
    if kind == "normal":
        return _normal_logpdf(x, args[:, 0], np.abs(args[:, 1]))
    if kind == "uniform":
        a, b = _uniform_bounds(args)
        width = b - a
        inside = (x >= a) & (x <= b)
        dens = np.where(width > 0, -_log(np.where(width > 0, width, 1.0)), 0.0)
        point_ok = (width > 0) | (x == a)
        return np.where(inside & point_ok, dens, -np.inf)
    if kind == "bernoulli":
        p = np.clip(args[:, 0], 0.0, 1.0)
        out = np.where(x == 1.0, _log(p), _log(1.0 - p))
        return np.where((x == 0.0) | (x == 1.0), out, -np.inf)
    if kind == "categorical":
        if args.shape[0] > 1 and (args == args[0]).all():  # one distribution for all rows
            return _categorical_logpmf(_categorical_probs(site, args[:1]),
                                       x, rows=np.zeros(len(x), dtype=np.intp))
        return _categorical_logpmf(_categorical_probs(site, args), x)
    raise ProgramError(f"site {site.id}: unknown kind {kind!r}")


# --------------------------------------------------------------------------- proposals


def _mixture(params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split `(n, 3K)` mixture params into normalized log weights, means, log sds."""
    params = np.asarray(params, dtype=np.float64)
    if params.ndim != 2 or params.shape[1] % 3 != 0 or params.shape[1] == 0:
        raise ValueError(f"mixture params must be (n, 3K), got shape {params.shape}")
    k = params.shape[1] // 3
    logw = params[:, :k]
    logw = logw - _logsumexp_rows(logw)[:, None]
    return logw, params[:, k : 2 * k], params[:, 2 * k :]


def _logsumexp_rows(a: np.ndarray) -> np.ndarray:
    m = np.max(a, axis=1)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        out: np.ndarray = m + np.log(np.sum(np.exp(a - m[:, None]), axis=1))
    return out


def _mixture_sample(
    logw: np.ndarray, mean: np.ndarray, sd: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    comp = _categorical_sample(np.exp(logw), rng).astype(np.intp)
    rows = np.arange(logw.shape[0])
    return mean[rows, comp] + sd[rows, comp] * rng.standard_normal(logw.shape[0])


def _mixture_logpdf(
    x: np.ndarray, logw: np.ndarray, mean: np.ndarray, sd: np.ndarray
) -> np.ndarray:
    comp = logw + _normal_logpdf(x[:, None], mean, sd)
    return _logsumexp_rows(comp)


def _normal_mixture(args: np.ndarray, params: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    logw, m, s = _mixture(params)
    mu = args[:, 0:1]
    sigma = np.abs(args[:, 1:2])
    return logw, mu + sigma * m, sigma * np.exp(s)


def _probs(params: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(params, dtype=np.float64), 0.0, None)
    total = p.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = p / total
    out: np.ndarray = np.where(total > 0, p, 1.0 / p.shape[1])
    return out


def temper(kind: str, params: np.ndarray, temperature: float = 1.0,
           choice_temperature: float = 1.0) -> np.ndarray:
    """Guide outputs of a sharper (< 1) or flatter (> 1) proposal, in the same layout.

    Choices (bernoulli, categorical): probabilities `p ** (1 / choice_temperature)`,
    renormalized. Mixtures (normal, uniform): log weights `/ temperature`, sds
    `* sqrt(temperature)` (each component's density to the power `1 / temperature`). The
    result is an ordinary proposal, so SMC weights with it stay exact."""
    if kind in ("bernoulli", "categorical"):
        if choice_temperature == 1.0:
            return params
        p = np.clip(np.asarray(params, dtype=np.float64), 0.0, 1.0 if kind == "bernoulli"
                    else None)
        if kind == "bernoulli":
            p = np.concatenate([p[:, :1], 1.0 - p[:, :1]], axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            logp = np.log(p) / choice_temperature
            logp -= _logsumexp_rows(logp)[:, None]
        q = np.exp(logp)
        empty = ~np.isfinite(logp).any(axis=1)  # all-zero rows stay as they were
        q[empty] = p[empty]
        return q[:, :1] if kind == "bernoulli" else q
    if temperature == 1.0:
        return params
    out = np.array(params, dtype=np.float64)
    k = out.shape[1] // 3
    out[:, :k] /= temperature
    out[:, 2 * k:] += 0.5 * math.log(temperature)
    return out


def proposal_sample(
    site: Site, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Draw one value per row from the proposal that `params` (guide outputs) describe."""
    args = _check_args(site, args)
    kind = site.kind
    n = args.shape[0]
    if kind == "normal":
        return _mixture_sample(*_normal_mixture(args, params), rng)
    if kind == "uniform":
        logw, m, s = _mixture(params)
        z = _mixture_sample(logw, m, np.exp(s), rng)
        a, b = _uniform_bounds(args)
        out: np.ndarray = a + (b - a) / (1.0 + np.exp(-z))
        return out
    if kind == "bernoulli":
        p = np.clip(np.asarray(params, dtype=np.float64)[:, 0], 0.0, 1.0)
        return (rng.random(n) < p).astype(np.float64)
    if kind == "categorical":
        return _categorical_sample(_probs(params), rng)
    raise ProgramError(f"site {site.id}: unknown kind {kind!r}")


def proposal_logpdf(
    site: Site, args: np.ndarray, params: np.ndarray, values: np.ndarray
) -> np.ndarray:
    """Log density of `values` under the proposal that `params` describe, shape `(n,)`."""
    args = _check_args(site, args)
    x = np.asarray(values, dtype=np.float64)
    kind = site.kind
    if kind == "normal":
        return _mixture_logpdf(x, *_normal_mixture(args, params))
    if kind == "uniform":
        logw, m, s = _mixture(params)
        a, b = _uniform_bounds(args)
        width = b - a
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (x - a) / width
            z = np.log(u) - np.log1p(-u)
            # log |dx/dz| = log(width) + log(u) + log(1 - u)
            out = _mixture_logpdf(z, logw, m, np.exp(s)) - (
                np.log(width) + np.log(u) + np.log1p(-u)
            )
        ok = (width > 0) & (u > 0) & (u < 1)
        return np.where(ok & ~np.isnan(out), out, -np.inf)
    if kind == "bernoulli":
        p = np.clip(np.asarray(params, dtype=np.float64)[:, 0], 0.0, 1.0)
        out = np.where(x == 1.0, _log(p), _log(1.0 - p))
        return np.where((x == 0.0) | (x == 1.0), out, -np.inf)
    if kind == "categorical":
        return _categorical_logpmf(_probs(params), x)
    raise ProgramError(f"site {site.id}: unknown kind {kind!r}")


_SMALL = 16  # rows up to which the categorical draw runs in plain Python
_SMALL_NORMAL = 4  # the same for the normal mixture (its rows cost more)


def _small_categorical_draw(
    p: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray] | None:
    """The categorical branch of `proposal_draw` for a few rows and fewer than 8 categories,
    in plain Python with numpy's arithmetic (numpy's row sums, sequential cumulative sums
    as np.cumsum, the same divisions and log), so the results are identical; None when
    some row has a
    negative, non-finite or all-zero weight (the general path handles those)."""
    rows = p.tolist()
    totals = p.sum(axis=1).tolist()  # numpy's summation order, as in _probs
    cums = []
    for row, total in zip(rows, totals, strict=True):
        if not (0.0 < total < math.inf) or min(row) < 0.0:
            return None
        cums.append(list(accumulate(row)))
    last = len(rows[0]) - 1
    us = rng.random(len(rows)).tolist()
    ks = []
    qs = []
    for row, cum, total, u in zip(rows, cums, totals, us, strict=True):
        x = u * cum[-1]
        k = 0
        for c in cum:
            if c <= x:
                k += 1
        k = min(k, last)
        ks.append(float(k))
        qs.append(row[k] / total)
    q = np.array(qs)
    return np.array(ks), (np.log(q) if min(qs) > 0.0 else _log(q))


def proposal_draw(
    site: Site, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """`proposal_sample` and `proposal_logpdf` of the drawn values in one pass: returns
    (values, log q). The log q values equal `proposal_logpdf(site, args, params, values)`."""
    args = _check_args(site, args)
    kind = site.kind
    n = args.shape[0]
    if kind == "categorical":
        p = np.asarray(params, dtype=np.float64)
        if n <= _SMALL and p.shape[1] < 8:
            out = _small_categorical_draw(p, rng)
            if out is not None:
                return out
        if (p >= 0).all():
            total = p.sum(axis=1)
            if (total > 0).all():
                cum = np.cumsum(p, axis=1)
                u = rng.random(n) * cum[:, -1]
                k = np.minimum((cum <= u[:, None]).sum(axis=1), p.shape[1] - 1)
                rows = np.arange(n)
                # the same arithmetic as _probs, so log q equals proposal_logpdf's
                return k.astype(np.float64), _log(p[rows, k] / total)
        probs = _probs(p)
        v = _categorical_sample(probs, rng)
        return v, _log(probs[np.arange(n), v.astype(np.intp)])
    if kind == "bernoulli":
        p = np.clip(np.asarray(params, dtype=np.float64)[:, 0], 0.0, 1.0)
        v = (rng.random(n) < p).astype(np.float64)
        return v, _log(np.where(v == 1.0, p, 1.0 - p))
    if kind == "normal":
        if n <= _SMALL_NORMAL:
            out = _small_normal_draw(args, params, rng)
            if out is not None:
                return out
        else:
            out = _lean_normal_draw(args, params, rng)
            if out is not None:
                return out
        logw, mean, sd = _normal_mixture(args, params)
        v = _mixture_sample(logw, mean, sd, rng)
        return v, _mixture_logpdf(v, logw, mean, sd)
    if kind == "uniform":
        v = proposal_sample(site, args, params, rng)
        return v, proposal_logpdf(site, args, params, v)
    raise ProgramError(f"site {site.id}: unknown kind {kind!r}")


def _lean_normal_draw(
    args: np.ndarray, params: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray] | None:
    """The normal-mixture branch of `proposal_draw` with fewer numpy calls, for finite
    parameters and positive sds: the same draws from `rng` (one uniform per row for the
    component, then one standard normal per row) and the same formulas as the general
    path (`_normal_mixture`, `_mixture_sample`, `_mixture_logpdf`); None otherwise."""
    p = np.asarray(params, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] % 3 != 0 or p.shape[1] == 0 or not np.isfinite(p).all():
        return None
    n, k = p.shape[0], p.shape[1] // 3
    sigma = np.abs(args[:, 1:2])
    sd = sigma * np.exp(p[:, 2 * k:])
    if not sd.min() > 0.0:
        return None
    lw = p[:, :k]
    top = lw.max(axis=1, keepdims=True)
    logw = lw - (top + np.log(np.exp(lw - top).sum(axis=1, keepdims=True)))
    mean = args[:, 0:1] + sigma * p[:, k:2 * k]
    cum = np.cumsum(np.exp(logw), axis=1)
    u = rng.random(n) * cum[:, -1]
    at = np.minimum((cum <= u[:, None]).sum(axis=1), k - 1) + np.arange(n) * k
    v = mean.reshape(-1)[at] + sd.reshape(-1)[at] * rng.standard_normal(n)
    z = (v[:, None] - mean) / sd
    comp = logw + (-0.5 * z * z - np.log(sd) - 0.5 * LOG_2PI)
    top = comp.max(axis=1, keepdims=True)
    return v, (top + np.log(np.exp(comp - top).sum(axis=1, keepdims=True)))[:, 0]


def _small_normal_draw(
    args: np.ndarray, params: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray] | None:
    """The normal-mixture branch of `proposal_draw` for a few rows, in plain Python: the
    same draws from `rng` (one uniform per row for the component, then one standard normal
    per row) and the same formulas as the array path, equal to it up to rounding; None
    when a row has non-finite numbers or a zero sd (the array path handles those)."""
    p = np.asarray(params, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] % 3 != 0 or p.shape[1] == 0:
        return None
    k = p.shape[1] // 3
    rows = p.tolist()
    mus = args[:, 0].tolist()
    sigmas = np.abs(args[:, 1]).tolist()
    mixes = []
    exp, log = math.exp, math.log
    for row, mu, sigma in zip(rows, mus, sigmas, strict=True):
        lw = row[:k]
        top = max(lw)
        if not (math.isfinite(top) and sigma > 0.0 and math.isfinite(math.fsum(row))):
            return None
        lse = top + log(sum(exp(x - top) for x in lw))
        lw = [x - lse for x in lw]
        means = [mu + sigma * m for m in row[k:2 * k]]
        sds = [sigma * exp(x) for x in row[2 * k:]]
        if min(sds) <= 0.0 or not all(math.isfinite(x) for x in sds + means):
            return None
        mixes.append((lw, means, sds))
    us = rng.random(len(rows)).tolist()
    zs = rng.standard_normal(len(rows)).tolist()
    values = []
    log_q = []
    for (lw, means, sds), u, z in zip(mixes, us, zs, strict=True):
        cum = list(accumulate(exp(x) for x in lw))
        x = u * cum[-1]
        c = min(sum(1 for y in cum if y <= x), k - 1)
        v = means[c] + sds[c] * z
        comp = [w - 0.5 * ((v - m) / sd) ** 2 - log(sd) - 0.5 * LOG_2PI
                for w, m, sd in zip(lw, means, sds, strict=True)]
        top = max(comp)
        if top == -math.inf:
            log_q.append(-math.inf)
        else:
            log_q.append(top + log(sum(exp(y - top) for y in comp)))
        values.append(v)
    return np.array(values), np.array(log_q)
