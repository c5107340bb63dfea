"""The site kinds, in one table (docs/architecture.md sections 4, 5): `KINDS[site.kind]`.

A kind says, for a site of its kind: the prior arguments (`n_args`, `args_problem`), the
guide network's output (`n_out`, `columns`, `head`: the network's last operation), the prior
(`prior_draw`, `prior_logpdf`), the proposal the network's outputs describe
(`proposal_sample`, `proposal_logpdf`, `proposal_draw`), its tempering (`temper`), what
valid outputs are (`output_problem`) and the networks' training targets (`to_z`). The
runtime (program.py, distributions.py, smc.py, proposals.py, guide.py, guide_checks.py) and
the compiler (language/checker.py, expr.py, codegen.py; learning/nets.py, export.py) ask
this table instead of switching on kind names; a new kind is one more entry here.

Arrays are batched over `n` particles: `args` is `(n, n_args)` float64, `params` `(n,
n_out)` (guide outputs), `values` `(n,)` float64. Log densities are float64; impossible
values give -inf, never NaN. Guide parameter layouts, `K` mixture components:
- normal: columns `[0:K]` log mixture weights (normalized here), `[K:2K]` means and
  `[2K:3K]` log sds, in prior units: `mean = mu + sigma * m`, `sd = sigma * exp(s)`.
- uniform on `(a, b)`: the same `(n, 3K)` layout for a normal mixture on `z`, and
  `x = a + (b - a) * sigmoid(z)`.
- bernoulli: `(n, 1)` probability of 1; categorical: `(n, k)` probabilities (normalized here).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import accumulate
from typing import Protocol

import numpy as np

from ngpm_runtime.errors import ProgramError

LOG_2PI = float(np.log(2.0 * np.pi))
MIXTURE, SIGMOID, SOFTMAX = "mixture", "sigmoid", "softmax"  # the heads of guide networks
_NO_ROWS = np.zeros(0)
_NO_OUT = np.zeros((0, 3))


class SiteRef(Protocol):
    """What the table reads of a site (program.Site) for its error messages."""

    @property
    def id(self) -> str: ...

    @property
    def line(self) -> int: ...


class SiteKind:
    """One kind of site: its prior, its guide network's outputs and their proposal."""

    name = ""
    code = -1  # the kind's number in the compiled kernels (kernels.NORMAL, ...)
    n_fixed: int | None = None  # prior arguments; None: one weight per category (k)
    continuous = False  # a float value (else an index or 0/1)
    head = SOFTMAX  # the guide network's last operation (MIXTURE, SIGMOID or SOFTMAX)
    finite_args = True  # the prior arguments must be finite (categorical checks its own)
    z_sd0 = 1.0  # mixtures: the sd of z whose proposal is close to the prior
    prior_normals = False  # prior_draw draws standard normals (else uniforms in [0, 1))

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
        return self.proposal_draw(args, params, rng)[0]

    def proposal_logpdf(self, args: np.ndarray, params: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Log density of values `x` under the proposal that `params` describe."""
        raise NotImplementedError

    def proposal_draw(
        self, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """One value per row from the proposal and its log density (`proposal_logpdf` of
        it, to rounding), by the compiled kernel (kernels.guide_round): one uniform per
        row, then, for mixtures, one standard normal per row."""
        n = int(args.shape[0])
        p = self.checked_params(params, n)
        u = rng.random(n)
        z = rng.standard_normal(n) if self.head == MIXTURE else _NO_ROWS
        out = np.empty((n, 3))
        _run_rows(self.code, p, args, u, z, out, 1.0, 1.0)
        return out[:, 0].copy(), out[:, 1].copy()

    def temper(
        self, params: np.ndarray, temperature: float, choice_temperature: float
    ) -> np.ndarray:
        """Guide outputs of a sharper (< 1) or flatter (> 1) proposal, same layout
        (mixtures: log weights / temperature, log sds + log(temperature) / 2; choices:
        probabilities ** (1 / choice_temperature), renormalized), by the compiled kernel;
        `params` itself when nothing changes."""
        t = float(temperature) if self.head == MIXTURE else 1.0
        tc = 1.0 if self.head == MIXTURE else float(choice_temperature)
        if t == 1.0 and tc == 1.0:
            return params
        p = self.checked_params(params, np.shape(params)[0])
        _run_rows(self.code, p, np.zeros((len(p), 0)), _NO_ROWS, _NO_ROWS, _NO_OUT, t, tc)
        return p

    def checked_params(self, params: np.ndarray, n: int) -> np.ndarray:
        """`params` as a new (n, m) float64 array of a width this kind reads (ValueError
        otherwise)."""
        p = np.array(params, dtype=np.float64, order="C", ndmin=2)
        m = p.shape[1] if p.ndim == 2 else 0
        ok = m % 3 == 0 and m > 0 if self.head == MIXTURE else m >= 1
        if p.ndim != 2 or p.shape[0] != n or not ok:
            raise ValueError(
                f"{self.name} proposal params must be (n, {'3K' if self.head == MIXTURE else 'k'})"
                f" for {n} rows, got shape {p.shape}"
            )
        return p

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

    def output_problem(self, out: np.ndarray, K: int, tol: float) -> str:
        total = np.logaddexp.reduce(out[:, :K], axis=1)
        return "" if np.abs(total).max() < tol else "mixture weights that do not sum to 1"


class Normal(_Mixture):
    """gauss(mu, sigma): prior arguments (mu, sigma); sigma == 0 is a point mass."""

    name = "normal"
    code = 0
    prior_normals = True

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

    def proposal_logpdf(self, args: np.ndarray, params: np.ndarray, x: np.ndarray) -> np.ndarray:
        return _mixture_logpdf(x, *_normal_mixture(args, params))

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
    code = 1
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


class Bernoulli(_Choice):
    """flip(p): prior argument (p,); values 0.0 and 1.0."""

    name = "bernoulli"
    code = 2
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

    def proposal_logpdf(self, args: np.ndarray, params: np.ndarray, x: np.ndarray) -> np.ndarray:
        return _bernoulli_logpmf(np.asarray(params, dtype=np.float64)[:, 0], x)


class Categorical(_Choice):
    """categorical(w_1, ..., w_k) and stochastic production groups (`choose`): the prior
    arguments are the k weights, normalized; values are indices 0..k-1."""

    name = "categorical"
    code = 3
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

    def proposal_logpdf(self, args: np.ndarray, params: np.ndarray, x: np.ndarray) -> np.ndarray:
        return _categorical_logpmf(_probs(params), x)


KINDS: dict[str, SiteKind] = {k.name: k for k in (Normal(), Uniform(), Bernoulli(), Categorical())}
SITE_KINDS = tuple(KINDS)


def numbers_text(values: Sequence[object]) -> str:
    """The first few values for a message: `1, -1` or `1, 2, ... (300 values)`."""
    shown = ", ".join(f"{v:g}" if isinstance(v, float) else repr(v) for v in values[:6])
    return shown if len(values) <= 6 else f"{shown}, ... ({len(values)} values)"


# --------------------------------------------------------------------------- helpers


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
    result: np.ndarray = np.where(np.isnan(out), -np.inf, out)
    return result


def _bernoulli_logpmf(p: np.ndarray, x: np.ndarray) -> np.ndarray:
    """log P(x) for values 0/1 with probabilities of 1 `p` (clipped into [0, 1])."""
    p = np.clip(p, 0.0, 1.0)
    out = np.where(x == 1.0, _log(p), _log(1.0 - p))
    result: np.ndarray = np.where((x == 0.0) | (x == 1.0), out, -np.inf)
    return result


def _categorical_probs(site: SiteRef, w: np.ndarray) -> np.ndarray:
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


def _categorical_logpmf(
    p: np.ndarray, values: np.ndarray, rows: np.ndarray | None = None
) -> np.ndarray:
    """log p[row, value] per value; `rows` picks the row of `p` for each value
    (default: row i for value i)."""
    v = np.asarray(values)
    ok = (v >= 0) & (v < p.shape[1]) & (v == np.floor(v))
    k = np.where(ok, v, 0).astype(np.intp)
    out = _log(p[np.arange(p.shape[0]) if rows is None else rows, k])
    result: np.ndarray = np.where(ok, out, -np.inf)
    return result


def _uniform_bounds(args: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.minimum(args[:, 0], args[:, 1])
    b = np.maximum(args[:, 0], args[:, 1])
    return a, b


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


def _mixture_logpdf(
    x: np.ndarray, logw: np.ndarray, mean: np.ndarray, sd: np.ndarray
) -> np.ndarray:
    comp = logw + _normal_logpdf(x[:, None], mean, sd)
    return _logsumexp_rows(comp)


def _normal_mixture(
    args: np.ndarray, params: np.ndarray
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


def _run_rows(
    code: int,
    params: np.ndarray,
    args: np.ndarray,
    u: np.ndarray,
    z: np.ndarray,
    out: np.ndarray,
    temperature: float,
    choice_temperature: float,
) -> None:
    """kernels.guide_round over rows of one kind without a network: params tempered in
    place; with `out` rows, values and log q drawn into out[:, :2]."""
    from ngpm_runtime import kernels  # numba loads at the first draw

    n, m = params.shape
    a = np.ascontiguousarray(args, dtype=np.float64)
    kernels.guide_round(
        _NO_X,
        np.zeros(n, dtype=np.int64),
        _NO_NET,
        _NO_W,
        _NO_COLS,
        np.array([code], dtype=np.int64),
        np.array([temperature, choice_temperature]),
        params,
        np.full(n, m, dtype=np.int64),
        a,
        np.full(n, a.shape[1] if a.ndim == 2 else 0, dtype=np.int64),
        u,
        z,
        out,
    )


_NO_X = np.zeros((0, 0), dtype=np.float32)
_NO_NET = np.zeros((1, 12), dtype=np.int64)  # one site without a network (kernels.NET_COLS)
_NO_W = np.zeros(0, dtype=np.float32)
_NO_COLS = np.zeros(0, dtype=np.int64)
