"""The numpy site kinds the compiled draws replaced (ngpm_runtime/kernels.py guide_round),
kept as the tests' reference: this module is runtime/ngpm_runtime/inference/sitekinds.py
before the kernels (git history), whose proposal_draw, proposal_sample and temper the
kernel's draws, log densities and tempering are compared with."""

from __future__ import annotations

import math
from itertools import accumulate

import numpy as np

# the helpers the compiled kernels did not replace are the runtime's own
from ngpm_runtime.inference.sitekinds import (
    SiteRef,
    _bernoulli_logpmf,
    _categorical_logpmf,
    _categorical_probs,
    _categorical_sample,
    _log,
    _logsumexp_rows,
    _mixture,
    _mixture_logpdf,
    _normal_logpdf,
    _normal_mixture,
    _probs,
    _uniform_bounds,
    numbers_text,
)

LOG_2PI = float(np.log(2.0 * np.pi))
MIXTURE, SIGMOID, SOFTMAX = "mixture", "sigmoid", "softmax"  # the heads of guide networks
_SMALL = 16  # rows up to which the categorical draw runs in plain Python
_SMALL_NORMAL = 4  # the same for the normal mixture (its rows cost more)


class SiteKind:
    """One kind of site: its prior, its guide network's outputs and their proposal."""

    name = ""
    n_fixed: int | None = None  # prior arguments; None: one weight per category (k)
    continuous = False  # a float value (else an index or 0/1)
    head = SOFTMAX  # the guide network's last operation (MIXTURE, SIGMOID or SOFTMAX)
    finite_args = True  # the prior arguments must be finite (categorical checks its own)
    z_sd0 = 1.0  # mixtures: the sd of z whose proposal is close to the prior

    @property
    def weighted(self) -> bool:
        """The prior arguments are the categories' weights (as many as the site's k)."""
        return self.n_fixed is None

    def n_args(self, k: int) -> int:
        """Number of prior arguments of a site with `k` categories."""
        return k if self.n_fixed is None else self.n_fixed

    def n_out(self, K: int, k: int) -> int:
        """Width of the guide network's output: K mixture components, k categories."""
        return sum(width for _, width in self.columns(K, k))

    def columns(self, K: int, k: int) -> tuple[tuple[str, int], ...]:
        """The network's output columns, in order, as (role, width): roles "logw",
        "mean", "logsd" (mixtures) or "prob"."""
        raise NotImplementedError

    def args_problem(self, vals: list[float], constant: bool) -> str:
        """What is wrong with finite prior arguments of the right number ("" if nothing)."""
        raise NotImplementedError

    def prior_draw(
        self, site: SiteRef, args: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """One value per row of `args` from the prior, and its log prior."""
        raise NotImplementedError

    def prior_logpdf(self, site: SiteRef, args: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Log prior density (or mass) of values `x`, shape `(n,)`."""
        raise NotImplementedError

    def proposal_sample(
        self, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """One value per row from the proposal that `params` (guide outputs) describe."""
        raise NotImplementedError

    def proposal_logpdf(self, args: np.ndarray, params: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Log density of values `x` under the proposal that `params` describe."""
        raise NotImplementedError

    def proposal_draw(
        self, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """`proposal_sample` and the drawn values' `proposal_logpdf` in one pass."""
        v = self.proposal_sample(args, params, rng)
        return v, self.proposal_logpdf(args, params, v)

    def temper(
        self, params: np.ndarray, temperature: float, choice_temperature: float
    ) -> np.ndarray:
        """Guide outputs of a sharper (< 1) or flatter (> 1) proposal, same layout."""
        raise NotImplementedError

    def output_problem(self, out: np.ndarray, K: int, tol: float) -> str:
        """Why finite network outputs `out` are not proposal parameters ("" if they are)."""
        raise NotImplementedError

    def to_z(
        self, values: np.ndarray, args: np.ndarray, eps: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Values in the networks' target space, and log |dz/dx| (discrete: the index, 0);
        uniform values are kept `eps` inside their bounds."""
        return np.rint(values), np.zeros(len(values))


class _Mixture(SiteKind):
    """A continuous kind whose proposal is a K-component normal mixture on z."""

    continuous = True
    head = MIXTURE
    n_fixed = 2

    def columns(self, K: int, k: int) -> tuple[tuple[str, int], ...]:
        return (("logw", K), ("mean", K), ("logsd", K))

    def temper(
        self, params: np.ndarray, temperature: float, choice_temperature: float
    ) -> np.ndarray:
        """Log weights `/ temperature`, sds `* sqrt(temperature)` (each component's
        density to the power `1 / temperature`)."""
        if temperature == 1.0:
            return params
        out = np.array(params, dtype=np.float64)
        k = out.shape[1] // 3
        out[:, :k] /= temperature
        out[:, 2 * k :] += 0.5 * math.log(temperature)
        return out

    def output_problem(self, out: np.ndarray, K: int, tol: float) -> str:
        total = np.logaddexp.reduce(out[:, :K], axis=1)
        return "" if np.abs(total).max() < tol else "mixture weights that do not sum to 1"


class Normal(_Mixture):
    """gauss(mu, sigma): prior arguments (mu, sigma); sigma == 0 is a point mass."""

    name = "normal"

    def args_problem(self, vals: list[float], constant: bool) -> str:
        if vals[1] < 0 or (constant and vals[1] == 0):
            return f"the standard deviation must be {'>' if constant else '>='} 0, got {vals[1]:g}"
        return ""

    def prior_draw(
        self, site: SiteRef, args: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        z = rng.standard_normal(args.shape[0])
        sd = np.abs(args[:, 1])
        if (sd > 0).all():
            return args[:, 0] + sd * z, -0.5 * z * z - np.log(sd) - 0.5 * LOG_2PI
        v = args[:, 0] + sd * z
        return v, _normal_logpdf(v, args[:, 0], sd)

    def prior_logpdf(self, site: SiteRef, args: np.ndarray, x: np.ndarray) -> np.ndarray:
        return _normal_logpdf(x, args[:, 0], np.abs(args[:, 1]))

    def proposal_sample(
        self, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        return _mixture_sample(*_normal_mixture(args, params), rng)

    def proposal_logpdf(self, args: np.ndarray, params: np.ndarray, x: np.ndarray) -> np.ndarray:
        return _mixture_logpdf(x, *_normal_mixture(args, params))

    def proposal_draw(
        self, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        if args.shape[0] <= _SMALL_NORMAL:
            out = _small_normal_draw(args, params, rng)
        else:
            out = _lean_normal_draw(args, params, rng)
        if out is not None:
            return out
        logw, mean, sd = _normal_mixture(args, params)
        v = _mixture_sample(logw, mean, sd, rng)
        return v, _mixture_logpdf(v, logw, mean, sd)

    def to_z(
        self, values: np.ndarray, args: np.ndarray, eps: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """z = (x - mu) / sigma; log q(x) = log q(z) - log sigma."""
        mu, sigma = args[:, 0], args[:, 1]
        return (values - mu) / sigma, -np.log(sigma)


class Uniform(_Mixture):
    """uniform(a, b): prior arguments (a, b); a == b is a point mass. The proposal is
    logit-normal: x = a + (b - a) sigmoid(z), z a normal mixture."""

    name = "uniform"
    z_sd0 = 1.7  # logit-normal(0, 1.7) is close to uniform(0, 1)

    def args_problem(self, vals: list[float], constant: bool) -> str:
        if vals[0] > vals[1] or (constant and vals[0] == vals[1]):
            return f"needs a {'<' if constant else '<='} b, got a = {vals[0]:g}, b = {vals[1]:g}"
        return ""

    def prior_draw(
        self, site: SiteRef, args: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        a, b = _uniform_bounds(args)
        width = b - a
        v = a + width * rng.random(args.shape[0])
        return v, -_log(np.where(width > 0, width, 1.0))

    def prior_logpdf(self, site: SiteRef, args: np.ndarray, x: np.ndarray) -> np.ndarray:
        a, b = _uniform_bounds(args)
        width = b - a
        inside = (x >= a) & (x <= b)
        dens = np.where(width > 0, -_log(np.where(width > 0, width, 1.0)), 0.0)
        point_ok = (width > 0) | (x == a)
        out: np.ndarray = np.where(inside & point_ok, dens, -np.inf)
        return out

    def proposal_sample(
        self, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        logw, m, s = _mixture(params)
        z = _mixture_sample(logw, m, np.exp(s), rng)
        a, b = _uniform_bounds(args)
        out: np.ndarray = a + (b - a) / (1.0 + np.exp(-z))
        return out

    def proposal_logpdf(self, args: np.ndarray, params: np.ndarray, x: np.ndarray) -> np.ndarray:
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
        result: np.ndarray = np.where(ok & ~np.isnan(out), out, -np.inf)
        return result

    def to_z(
        self, values: np.ndarray, args: np.ndarray, eps: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """z = logit((x - a) / (b - a)); log q(x) = log q(z) - log((b - a) u (1 - u))."""
        a, b = args[:, 0], args[:, 1]
        u = np.clip((values - a) / (b - a), eps, 1 - eps)
        return np.log(u) - np.log1p(-u), -np.log((b - a) * u * (1 - u))


class _Choice(SiteKind):
    """A discrete kind whose proposal is a probability per value."""

    def columns(self, K: int, k: int) -> tuple[tuple[str, int], ...]:
        return (("prob", 1 if self.head == SIGMOID else k),)

    def output_problem(self, out: np.ndarray, K: int, tol: float) -> str:
        if out.min() < 0 or out.max() > 1:
            return "probabilities outside [0, 1]"
        if self.head == SOFTMAX and np.abs(out.sum(axis=1) - 1).max() > tol:
            return "probabilities that do not sum to 1"
        return ""

    def temper(
        self, params: np.ndarray, temperature: float, choice_temperature: float
    ) -> np.ndarray:
        """Probabilities `p ** (1 / choice_temperature)`, renormalized."""
        if choice_temperature == 1.0:
            return params
        two = self.head == SIGMOID  # the probability of 1, and of 0
        p = np.clip(np.asarray(params, dtype=np.float64), 0.0, 1.0 if two else None)
        if two:
            p = np.concatenate([p[:, :1], 1.0 - p[:, :1]], axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            logp = np.log(p) / choice_temperature
            logp -= _logsumexp_rows(logp)[:, None]
        q = np.exp(logp)
        empty = ~np.isfinite(logp).any(axis=1)  # all-zero rows stay as they were
        q[empty] = p[empty]
        out: np.ndarray = q[:, :1] if two else q
        return out


class Bernoulli(_Choice):
    """flip(p): prior argument (p,); values 0.0 and 1.0."""

    name = "bernoulli"
    n_fixed = 1
    head = SIGMOID

    def args_problem(self, vals: list[float], constant: bool) -> str:
        return "" if 0 <= vals[0] <= 1 else f"the probability must be in [0, 1], got {vals[0]:g}"

    def prior_draw(
        self, site: SiteRef, args: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        p = np.clip(args[:, 0], 0.0, 1.0)
        v = (rng.random(args.shape[0]) < p).astype(np.float64)
        return v, _log(np.where(v == 1.0, p, 1.0 - p))

    def prior_logpdf(self, site: SiteRef, args: np.ndarray, x: np.ndarray) -> np.ndarray:
        return _bernoulli_logpmf(args[:, 0], x)

    def proposal_sample(
        self, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        p = np.clip(np.asarray(params, dtype=np.float64)[:, 0], 0.0, 1.0)
        out: np.ndarray = (rng.random(args.shape[0]) < p).astype(np.float64)
        return out

    def proposal_logpdf(self, args: np.ndarray, params: np.ndarray, x: np.ndarray) -> np.ndarray:
        return _bernoulli_logpmf(np.asarray(params, dtype=np.float64)[:, 0], x)

    def proposal_draw(
        self, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        p = np.clip(np.asarray(params, dtype=np.float64)[:, 0], 0.0, 1.0)
        v = (rng.random(args.shape[0]) < p).astype(np.float64)
        return v, _log(np.where(v == 1.0, p, 1.0 - p))


class Categorical(_Choice):
    """categorical(w_1, ..., w_k) and stochastic production groups (`choose`): the prior
    arguments are the k weights, normalized; values are indices 0..k-1."""

    name = "categorical"
    finite_args = False  # _categorical_probs checks the weights

    def args_problem(self, vals: list[float], constant: bool) -> str:
        if min(vals) < 0 or sum(vals) <= 0:
            return f"weights must be >= 0 with a positive sum, got {numbers_text(vals)}"
        return ""

    def prior_draw(
        self, site: SiteRef, args: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        n = args.shape[0]
        if n > 1 and (args == args[0]).all():  # one distribution for all rows (groups)
            w = args[0].tolist()
            total = math.fsum(w)
            if not (total > 0 and all(0.0 <= x < math.inf for x in w)):
                _categorical_probs(site, args[:1])  # raises the error
            cum = np.array(list(accumulate(w)))
            k = np.minimum(np.searchsorted(cum, rng.random(n) * cum[-1], side="right"), len(w) - 1)
            return k.astype(np.float64), _log(np.array(w) / total)[k]
        p = _categorical_probs(site, args)
        v = _categorical_sample(p, rng)
        return v, _log(p[np.arange(n), v.astype(np.intp)])

    def prior_logpdf(self, site: SiteRef, args: np.ndarray, x: np.ndarray) -> np.ndarray:
        if args.shape[0] > 1 and (args == args[0]).all():  # one distribution for all rows
            return _categorical_logpmf(
                _categorical_probs(site, args[:1]), x, rows=np.zeros(len(x), dtype=np.intp)
            )
        return _categorical_logpmf(_categorical_probs(site, args), x)

    def proposal_sample(
        self, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        return _categorical_sample(_probs(params), rng)

    def proposal_logpdf(self, args: np.ndarray, params: np.ndarray, x: np.ndarray) -> np.ndarray:
        return _categorical_logpmf(_probs(params), x)

    def proposal_draw(
        self, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        n = args.shape[0]
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


KINDS: dict[str, SiteKind] = {k.name: k for k in (Normal(), Uniform(), Bernoulli(), Categorical())}
SITE_KINDS = tuple(KINDS)


# --------------------------------------------------------------------------- helpers


def _mixture_sample(
    logw: np.ndarray, mean: np.ndarray, sd: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    comp = _categorical_sample(np.exp(logw), rng).astype(np.intp)
    rows = np.arange(logw.shape[0])
    out: np.ndarray = mean[rows, comp] + sd[rows, comp] * rng.standard_normal(logw.shape[0])
    return out


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
    sd = sigma * np.exp(p[:, 2 * k :])
    if not sd.min() > 0.0:
        return None
    lw = p[:, :k]
    top = lw.max(axis=1, keepdims=True)
    logw = lw - (top + np.log(np.exp(lw - top).sum(axis=1, keepdims=True)))
    mean = args[:, 0:1] + sigma * p[:, k : 2 * k]
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
        means = [mu + sigma * m for m in row[k : 2 * k]]
        sds = [sigma * exp(x) for x in row[2 * k :]]
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
        comp = [
            w - 0.5 * ((v - m) / sd) ** 2 - log(sd) - 0.5 * LOG_2PI
            for w, m, sd in zip(lw, means, sds, strict=True)
        ]
        top = max(comp)
        if top == -math.inf:
            log_q.append(-math.inf)
        else:
            log_q.append(top + log(sum(exp(y - top) for y in comp)))
        values.append(v)
    return np.array(values), np.array(log_q)
