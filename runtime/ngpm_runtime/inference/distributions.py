"""Batched densities and samplers of the site kinds (architecture.md sections 4, 5): the API
that SMC, the proposals and the guide call.

Every function works on `n` particles at once: `args` is `(n, n_args)` float64 (prior
arguments per section 4), `params` is `(n, n_params)` (guide outputs per section 5) and
`values` is `(n,)` float64. Log densities are float64; impossible values give -inf, never NaN.
Each looks the site's kind up in the one table, sitekinds.KINDS, which holds the per-kind
arithmetic and documents the parameter layouts.
"""

from __future__ import annotations

import numpy as np

from ngpm_runtime.errors import ProgramError
from ngpm_runtime.inference.sitekinds import KINDS, LOG_2PI, SiteKind
from ngpm_runtime.program import Site

__all__ = [
    "LOG_2PI",
    "kind_of",
    "prior_draw",
    "prior_logpdf",
    "prior_sample",
    "proposal_draw",
    "proposal_logpdf",
    "proposal_sample",
    "temper",
]


def kind_of(site: Site) -> SiteKind:
    """The site's kind in the table (ProgramError for an unknown kind)."""
    kind = KINDS.get(site.kind)
    if kind is None:
        raise ProgramError(f"site {site.id}: unknown kind {site.kind!r}")
    return kind


def _check_args(site: Site, args: np.ndarray) -> tuple[SiteKind, np.ndarray]:
    """The site's kind and its prior arguments as a 2-D float64 array (checked)."""
    args = np.asarray(args, dtype=np.float64)
    if args.ndim != 2:
        raise ValueError(f"prior args for site {site.id} must be 2-D, got shape {args.shape}")
    kind = kind_of(site)
    if kind.finite_args and not np.all(np.isfinite(args)):
        raise ProgramError(f"site {site.id} (line {site.line}): non-finite {site.kind} arguments")
    return kind, args


def prior_draw(
    site: Site, args: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Draw one value per row of `args` from the site's prior; returns (values, log prior)."""
    kind, args = _check_args(site, args)
    return kind.prior_draw(site, args, rng)


def prior_sample(site: Site, args: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Draw one value per row of `args` from the site's prior."""
    return prior_draw(site, args, rng)[0]


def prior_logpdf(site: Site, args: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Log prior density (or mass) of `values` under the site's prior, shape `(n,)`."""
    kind, args = _check_args(site, args)
    return kind.prior_logpdf(site, args, np.asarray(values, dtype=np.float64))


def temper(
    kind: str, params: np.ndarray, temperature: float = 1.0, choice_temperature: float = 1.0
) -> np.ndarray:
    """Guide outputs of a sharper (< 1) or flatter (> 1) proposal, in the same layout.

    Choices (bernoulli, categorical): probabilities `p ** (1 / choice_temperature)`,
    renormalized. Mixtures (normal, uniform): log weights `/ temperature`, sds
    `* sqrt(temperature)` (each component's density to the power `1 / temperature`). The
    result is an ordinary proposal, so SMC weights with it stay exact."""
    table = KINDS.get(kind)
    if table is None:
        raise ValueError(f"unknown site kind {kind!r}")
    return table.temper(params, temperature, choice_temperature)


def proposal_sample(
    site: Site, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Draw one value per row from the proposal that `params` (guide outputs) describe."""
    kind, args = _check_args(site, args)
    return kind.proposal_sample(args, params, rng)


def proposal_logpdf(
    site: Site, args: np.ndarray, params: np.ndarray, values: np.ndarray
) -> np.ndarray:
    """Log density of `values` under the proposal that `params` describe, shape `(n,)`."""
    kind, args = _check_args(site, args)
    return kind.proposal_logpdf(args, params, np.asarray(values, dtype=np.float64))


def proposal_draw(
    site: Site, args: np.ndarray, params: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """`proposal_sample` and `proposal_logpdf` of the drawn values in one pass: returns
    (values, log q). The log q values equal `proposal_logpdf(site, args, params, values)` (to
    rounding: the kernel's log and exp may round a last bit apart from numpy's)."""
    kind, args = _check_args(site, args)
    return kind.proposal_draw(args, params, rng)
