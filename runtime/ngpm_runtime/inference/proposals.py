"""Proposals that answer SMC's batched site requests (architecture.md section 5).

`PriorProposal` samples each site's prior. `FixedProposal` uses one fixed set of guide-style
parameters per site (tests and baselines); sites it does not list fall back to the prior.
A learned `Guide` (guide.py) implements the same protocol.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ngpm_runtime.errors import ProgramError
from ngpm_runtime.inference.distributions import (
    prior_draw,
    prior_logpdf,
    prior_sample,
    proposal_draw,
)
from ngpm_runtime.program import Site


class Proposal(Protocol):
    uses_features: bool
    # optional `feature_context: bool`: rows carry the context group (image/features.py)

    def propose(
        self,
        site: Site,
        prior_args: np.ndarray,
        features: np.ndarray | None,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass
class RoundRows:
    """The rows of one SMC round for a RoundProposal: the waiting sites `sites` (ascending),
    `counts[j]` particles at sites[j], one block after the other, each in particle order.
    Row r is at site index site[r] with prior arguments args[r, :n_args[r]] and, when
    features are given, the feature row features[r, :widths[j]] (float32; the columns
    past a site's width belong to no one)."""

    sites: list[Site]
    counts: list[int]
    site: np.ndarray  # (n,) int64
    args: np.ndarray  # (n, >= max n_args) float64
    n_args: np.ndarray  # (n,) int64
    features: np.ndarray | None  # (n, >= max width) float32
    widths: list[int]


@runtime_checkable
class RoundProposal(Protocol):
    """A proposal that also serves every site waiting in an SMC round with one call (a
    learned Guide: one network evaluation for all of them). `smc()` then hands it the
    rows of all waiting sites at once (`RoundRows`); it returns (n, 3) float64: per row
    the value, its log q and its log prior."""

    uses_features: bool

    def propose_rows(self, rows: RoundRows, rng: np.random.Generator) -> np.ndarray: ...


class PriorProposal:
    """Sample the prior: log q equals log prior, so site weights cancel."""

    uses_features = False

    def propose(
        self,
        site: Site,
        prior_args: np.ndarray,
        features: np.ndarray | None,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        return prior_draw(site, prior_args, rng)


class FixedProposal:
    """A fixed proposal per site: `params` maps a site index or id to one row of guide
    outputs (layouts in distributions.py), used for every particle at that site."""

    uses_features = False

    def __init__(self, params: Mapping[int | str, np.ndarray | list[float]]) -> None:
        self.params = {k: np.asarray(v, dtype=np.float64).reshape(1, -1) for k, v in params.items()}

    def _row(self, site: Site) -> np.ndarray | None:
        row = self.params.get(site.index)
        return row if row is not None else self.params.get(site.id)

    def propose(
        self,
        site: Site,
        prior_args: np.ndarray,
        features: np.ndarray | None,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        row = self._row(site)
        if row is None:
            values = prior_sample(site, prior_args, rng)
            return values, prior_logpdf(site, prior_args, values)
        params = np.repeat(row, prior_args.shape[0], axis=0)
        return proposal_draw(site, prior_args, params, rng)


class ReplayProposal:
    """Returns recorded values, site by site, with log q = log prior (weights unchanged):
    one particle replays one derivation. A different site or too few values is an error."""

    uses_features = False

    def __init__(self, values: list[tuple[int, float]]) -> None:
        self.values = list(values)
        self.pos = 0

    def propose(
        self,
        site: Site,
        prior_args: np.ndarray,
        features: np.ndarray | None,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        if prior_args.shape[0] != 1:
            raise ProgramError(f"replay runs one particle, got {prior_args.shape[0]}")
        if self.pos >= len(self.values):
            raise ProgramError(
                f"replay: site {site.id} asked for a value after the "
                f"{len(self.values)} recorded ones"
            )
        s, v = self.values[self.pos]
        if s != site.index:
            raise ProgramError(
                f"replay: recorded site {s} at choice {self.pos}, "
                f"the program asked for site {site.index} ({site.id})"
            )
        self.pos += 1
        values = np.array([float(v)])
        return values, prior_logpdf(site, prior_args, values)

    def check_used(self) -> None:
        if self.pos != len(self.values):
            raise ProgramError(f"replay used {self.pos} of {len(self.values)} recorded values")
