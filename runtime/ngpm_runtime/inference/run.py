"""One SMC run's state and step (architecture.md sections 2, 3, 5, 8): `smc()` (smc.py)
builds a `_Run` (this module: particles on the Python deriver, derive.Deriver) or a
`CompiledRun` (compiled_run.py: the population in arrays on the compiled deriver) and
steps it.

All particles advance together. In one step every live particle runs to its next drawn
primitive; the random values it asks for on the way are drawn in rounds. A proposal with
`propose_rows` (a learned Guide) serves every site that particles wait on in one call per
round (one network evaluation for all of them); any other proposal gets one batched
`propose` call per round for the particles waiting on one site (`SiteOrder` picks it).
A round with features or a RoundProposal packs its particles' state in one pass and
unpacks it with one kernel call into the run's arrays (`_round_rows`, `_Buffers`).
Particles are served in index order. Then the new primitives are rasterized, the likelihood
increments applied and, every step or when the ESS drops below `ess_threshold * N`, the
particles are resampled (in between, once some have finished, a live particle with a
negligible share of the weight plays Russian roulette: `Population.roulette`). Weights
carry `log prior - log q` of every site, so any proposal gives a correct answer.

The parts: `_Run.step` derives (`_derive`), serves the waiting sites (`_serve`, `_weigh`),
rasterizes and applies the likelihood (`_observe`) and resamples (`_resample`);
`Population` holds the particles and weights. Observers (`SMCObserver`: progress, live
frames, time limits) watch from outside: they hear of every served site, every finished
step and every resampling, and keep their own per-particle arrays in the run's `SMCState`,
which resampling carries along.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum
from itertools import chain
from typing import TYPE_CHECKING, Any, Protocol, cast, runtime_checkable

import numpy as np

from ngpm_runtime.errors import NgpmError, ProgramError, SMCFailed
from ngpm_runtime.geometry.cons import cons_to_list
from ngpm_runtime.geometry.derive import (
    DEFAULT_MAX_MODULES,
    DONE,
    DRAWN,
    NEED,
    Args,
    Deriver,
    Particle,
)
from ngpm_runtime.geometry.turtle import Prim, prim_bbox
from ngpm_runtime.image.raster import DrawBatch
from ngpm_runtime.inference.distributions import kind_of, prior_logpdf
from ngpm_runtime.inference.likelihood import Likelihood, NullLikelihood, PrimBatch
from ngpm_runtime.inference.proposals import PriorProposal, Proposal, RoundProposal, RoundRows
from ngpm_runtime.inference.resample import resample as draw_ancestors
from ngpm_runtime.program import Program, Site

if TYPE_CHECKING:
    from ngpm_runtime.volume.target import VolumeTarget


class SMCOptionError(NgpmError):
    """An SMC option has a value that cannot be used."""


class TraceRecording(Enum):
    """What each particle's trace records: nothing, (site, None, value) at no feature cost
    (`replay` adds the features afterwards), or (site, features, value)."""

    NONE = "none"
    VALUES = "values"
    FULL = "full"


@dataclass(frozen=True, eq=False)
class SMCOptions:
    """How `smc()` runs. ess_threshold: a fraction of N, resample only when ESS <
    ess_threshold * N (None: every step); ess_from_proposal: use the proposal's own
    `settings.ess_threshold` instead (a tuned Guide carries one; a proposal without settings
    resamples every step). max_primitives overrides `program.max_primitives`, max_modules
    `program.max_modules` (modules one particle may expand or interpret in one step).
    A 3D grammar: start may be (x, y, z, heading), volume is the 3D target the features
    read (a VolumeTarget; canvas_size and target_mask are 2D only)."""

    seed: int = 0
    resample: str = "residual"
    ess_threshold: float | None = None
    ess_from_proposal: bool = False
    trace: TraceRecording = TraceRecording.NONE
    start: tuple[float, ...] | None = None
    canvas_size: tuple[int, int] = (50, 50)
    target_mask: np.ndarray | None = None
    max_steps: int | None = None
    max_primitives: int | None = None
    max_modules: int | None = None
    volume: VolumeTarget | None = None


class SMCState:
    """What observers see of a run: the particle count, the steps so far, each particle's
    log-likelihood, the particles that drew in this step with their new primitives, and the
    per-particle arrays observers registered (resampling indexes every one of them)."""

    def __init__(self, n: int, log_likelihood: np.ndarray) -> None:
        self.n = n
        self.steps = 0
        self.log_likelihood = log_likelihood
        self.drawn: list[int] = []
        self.prims: list[Prim] = []
        self.arrays: dict[str, np.ndarray] = {}

    def register(self, name: str, array: np.ndarray) -> np.ndarray:
        """Keep `array` (one entry per particle) as `arrays[name]`, resampled with the
        particles; returns it."""
        if len(array) != self.n:
            raise SMCOptionError(
                f"per-particle array {name!r} has {len(array)} entries, "
                f"not one per particle ({self.n})"
            )
        self.arrays[name] = array
        return array


class SMCObserver:
    """Watches a run from outside (no-op defaults; subclass and override). An exception
    raised here ends the run (a time limit, a cancelled request)."""

    def site_drawn(self, site: Site, idx: list[int], values: list[float]) -> None:
        """Particles `idx` drew `values` at `site`."""

    def step_done(self, state: SMCState) -> None:
        """A step's primitives are drawn and weighed (before any resampling)."""

    def resampled(self, ancestors: np.ndarray) -> None:
        """Particle k became old particle ancestors[k] (`state.arrays` already follow)."""


class _HasEss(Protocol):
    ess_threshold: float | None


@runtime_checkable
class Tuned(Protocol):
    """A proposal that carries settings (a Guide's `ProposalSettings`)."""

    settings: _HasEss


def proposal_ess(proposal: Proposal | None) -> float | None:
    """The ESS threshold a proposal's settings ask for (None: resample every step)."""
    return proposal.settings.ess_threshold if isinstance(proposal, Tuned) else None


def take_arrays(arrays: dict[str, np.ndarray], anc: np.ndarray) -> None:
    """Resampling of per-particle arrays: entry k becomes old entry anc[k]."""
    for key in arrays:
        arrays[key] = arrays[key][anc]


@dataclass
class FinalParticle:
    primitives: list[Prim]
    log_prior: float
    log_likelihood: float
    log_weight: float
    trace: list[tuple[int, np.ndarray | None, float]] | None
    status: str  # "done", "limit" (a cap was hit) or "dead" (zero weight)
    limit: str | None = None  # which cap: "max modules", "max primitives" or "max steps"


@dataclass
class SMCResult:
    particles: list[FinalParticle]
    log_weights: np.ndarray
    best: FinalParticle
    log_evidence: float
    ess_history: list[float]
    steps: int
    seconds: float
    info: dict[str, Any] = field(default_factory=dict)


# a live particle's share of the weight below which it plays Russian roulette
# (Population.roulette); this small, it changed none of 48 held-out runs of the bundled
# vines guide (docs/results, "Circuits")
NEGLIGIBLE_LIVE = 1e-100
LOG_NEGLIGIBLE_LIVE = math.log(NEGLIGIBLE_LIVE)
_ROULETTE_STREAM = 0x524F55  # the roulette's random stream, beside the run's


def _logsumexp(a: np.ndarray, m: float | None = None) -> float:
    """log sum exp(a); m: a's max when known."""
    if m is None:
        m = float(np.max(a))
    if not math.isfinite(m):
        return m
    return m + math.log(float(np.sum(np.exp(a - m))))


def _ess(log_w: np.ndarray, m: float | None = None) -> tuple[float, float]:
    """(ESS, log sum exp(log_w)); m: log_w's max when known (2 m is then 2 log_w's, exactly:
    doubling a float is exact)."""
    if m is None:
        m = float(np.max(log_w))
    lse = _logsumexp(log_w, m)
    if not math.isfinite(lse):
        return 0.0, lse
    return float(math.exp(2.0 * lse - _logsumexp(2.0 * log_w, 2.0 * m))), lse


class Population:
    """The particles of one run and their weights; index i is particle i throughout.
    `live` lists the particles still deriving, ascending."""

    def __init__(self, parts: list[Particle]) -> None:
        n = len(parts)
        self.n = n
        self.parts = parts
        self.log_w = np.zeros(n)
        self.log_prior = np.zeros(n)
        self.log_lik = np.zeros(n)
        self.live = list(range(n))

    def add_loglik(self, idx: np.ndarray, inc: np.ndarray | float) -> None:
        self.log_w[idx] += inc
        self.log_lik[idx] += inc

    def update_live(self) -> None:
        """Zero-weight live particles are dead; `live` keeps the ones still deriving."""
        parts = self.parts
        for i in np.flatnonzero(self.log_w == -np.inf).tolist():
            if parts[i].status == "live":
                parts[i].status = "dead"
        self.live = [i for i in self.live if parts[i].status == "live"]

    def roulette(self, rng: np.random.Generator, log_share: float = LOG_NEGLIGIBLE_LIVE) -> bool:
        """Russian roulette for the live particles whose share of the total weight is below
        exp(log_share) (NEGLIGIBLE_LIVE): each stays with probability share / exp(log_share),
        its weight then raised to that share, else its weight becomes zero (it is dead).
        Exact in expectation, and every other particle stays as it is. `step` runs it once
        some particles have stopped, when resampling waits for a low ESS: a particle that
        ran away (far worse than the rest, growing to a cap) kept the run going for
        thousands of steps after the others had finished. Returns whether a weight changed."""
        log_w = self.log_w
        cut = _logsumexp(log_w) + log_share
        idx = np.asarray(self.live, dtype=np.intp)
        low = idx[log_w[idx] < cut]
        if not len(low):
            return False
        keep = np.log(rng.random(len(low))) < log_w[low] - cut
        log_w[low] = np.where(keep, cut, -np.inf)
        if not keep.all():
            self.update_live()  # the dropped ones: dead, out of `live`
        return True

    def take(self, anc: np.ndarray) -> None:
        """Resampling: particle k becomes old particle anc[k]; weights reset to 0."""
        self.parts, self.live = _take_particles(self.parts, anc)
        self.log_prior = self.log_prior[anc]
        self.log_lik = self.log_lik[anc]
        self.log_w = np.zeros(self.n)


class _Run:
    """One SMC run's state: population, canvas, features, proposal, observers, counters."""

    def __init__(
        self,
        program: Program,
        likelihood: Likelihood | None,
        n: int,
        proposal: Proposal | None,
        options: SMCOptions,
        observers: tuple[SMCObserver, ...],
    ) -> None:
        self.program = program
        self.n = n
        self.resample = options.resample
        self.trace = options.trace
        self.observers = observers
        self.rng = np.random.Generator(np.random.PCG64(options.seed))
        self.seed = options.seed
        self._roulette: np.random.Generator | None = None
        self.proposal: Proposal = PriorProposal() if proposal is None else proposal
        self.is_prior = type(self.proposal) is PriorProposal
        self.batched = isinstance(self.proposal, RoundProposal)
        cap = options.max_primitives
        self.cap = program.max_primitives if cap is None else int(cap)
        if isinstance(likelihood, NullLikelihood):
            likelihood = None  # nothing to compute, no canvas needed
        self.likelihood = likelihood
        self.settles = bool(likelihood is not None and likelihood.settles)
        self.use_features = bool(self.proposal.uses_features)
        self._make_canvas(options)
        self.like_state = likelihood.start(n) if likelihood is not None else {}
        self.blank_ll = (
            likelihood.blank_loglik(self.canvas.height, self.canvas.width)
            if likelihood is not None and self.canvas is not None
            else None
        )
        self.deriver = Deriver(program, max_modules=module_cap(program, options.max_modules))
        self.pop = self._population(options.start, n)
        self.state = SMCState(n, self.pop.log_lik)
        self.order = SiteOrder()
        # log prior of weighted (categorical) sites per (site, weights)
        self.tables: dict[tuple[int, Args], list[float]] = {}
        self.t_width = 0 if self.fmaker is None else int(self.fmaker.n_turtle)
        # feature columns per site
        fm = self.fmaker
        self.n_feat = [] if fm is None else [int(fm.n_features(s)) for s in program.sites]
        self.kernels: Any = None  # ngpm_runtime.kernels, when the run loads numba anyway
        if self.canvas is not None or self.batched or self.fmaker is not None:
            from ngpm_runtime import kernels

            self.kernels = kernels
        self.buffers = (
            _Buffers(program, n, self.t_width) if self.batched or self.fmaker is not None else None
        )
        # a guide whose kernel serves a whole round (Guide.round_tables), with 2D features
        self.round_tables: Any = None
        if self.batched and self.use_features and hasattr(self.fmaker, "window_args"):
            self.round_tables = getattr(self.proposal, "round_tables", None)
        self.width_ok: set[int] = set()  # sites whose feature width the guide accepted
        self.log_z = 0.0
        self.ess_history: list[float] = []
        self.steps = 0
        self.particle_steps = 0
        self.n_resample = 0

    def _population(self, start: Sequence[float] | None, n: int) -> Population:
        """The run's n particles at the start pose (start_particles)."""
        return Population(start_particles(self.deriver, self.program, start, n))

    def _make_canvas(self, options: SMCOptions) -> None:
        """The canvas (for a likelihood that needs one, or for features) and the feature
        maker (for a proposal that reads features, or full traces)."""
        program, likelihood = self.program, self.likelihood
        need_features = self.use_features or self.trace is TraceRecording.FULL
        self.trim = 0  # context columns to cut from the rows the proposal is given
        if program.dim == 3:  # voxel canvas, likelihood and features (volume/, issue #26)
            self._make_volume(options, need_features)
            return
        if options.volume is not None:
            raise SMCOptionError(f"{program.name} is a 2D grammar: a 3D target is for 3D ones")
        self.canvas = None
        if need_features or (likelihood is not None and likelihood.needs_canvas):
            if program.viewport is None:
                raise ProgramError(
                    f"program {program.name} has no viewport: "
                    "cannot rasterize for the likelihood or features"
                )
            from ngpm_runtime.image.raster import Canvas

            height, width = options.canvas_size
            self.canvas = Canvas(
                self.n, int(height), int(width), program.viewport, pyramid=need_features
            )
        self.fmaker = None
        if need_features:
            from ngpm_runtime.image.features import FeatureMaker

            # recorded traces carry the context and far columns; a guide reads them if
            # trained on them (optional attributes: proposals written before them read none)
            reads = bool(getattr(self.proposal, "feature_context", False))
            reads_far = bool(getattr(self.proposal, "feature_far", False))
            full = self.trace is TraceRecording.FULL
            assert program.viewport is not None  # checked for the canvas above
            self.fmaker = FeatureMaker(
                program, program.viewport, options.target_mask, full or reads, full or reads_far
            )
            from ngpm_runtime.image.features import N_CONTEXT, N_FAR

            self.trim = N_FAR * (full and not reads_far) + N_CONTEXT * (full and not reads)

    def _make_volume(self, options: SMCOptions, need_features: bool) -> None:
        """A 3D grammar's voxel canvas and FeatureMaker3D (volume/run.py) with the guide's
        window (a proposal without one: the default); they have the interface of the 2D
        ones that the run uses."""
        from ngpm_runtime.volume.run import canvas_and_features

        canvas, fmaker = canvas_and_features(
            self.program,
            self.likelihood,
            self.n,
            options.volume,
            need_features,
            options.target_mask,
            getattr(self.proposal, "feature_window", None),
        )
        self.canvas, self.fmaker = cast(Any, canvas), cast(Any, fmaker)

    def step(self, ess_threshold: float | None) -> None:
        """Every live particle to its next drawn primitive; weights; maybe resampling."""
        pop = self.pop
        self.steps += 1
        self.particle_steps += len(pop.live)
        before = pop.live
        drawn, empty = self._derive()
        self._observe(drawn, empty)
        if self.observers:
            self._step_done(drawn)
        top: float | None = self._top()  # one pass: +inf, all zero, the ESS
        if top != top:  # a NaN weight: the checks one by one
            top = None
        if top == np.inf or (top is None and (pop.log_w == np.inf).any()):
            raise SMCFailed(
                f"a weight became +inf at step {self.steps} (program "
                f"{self.program.name}): a proposal gave zero density to its own "
                "value or a likelihood returned +inf"
            )
        if top == -np.inf or (top is None and not np.isfinite(pop.log_w).any()):
            raise SMCFailed(
                f"every particle's weight is zero after step {self.steps} "
                f"({self.n} particles, program {self.program.name})"
            )
        self._update_live()
        if self.settles and len(pop.live) < len(before):
            now = set(pop.live)
            if self._settle([i for i in before if i not in now]):
                top = None  # weights changed
        if ess_threshold is not None and 0 < len(pop.live) < self.n:
            if pop.roulette(self._roulette_rng):
                top = None  # weights changed
        if self.kernels is None:  # a run that loads no kernels (a forward sample)
            ess, lse = _ess(pop.log_w, top)
        else:  # the same arithmetic, one call
            m = float(np.max(pop.log_w)) if top is None else top
            ess, lse = self.kernels.ess(pop.log_w, m)
        self.ess_history.append(ess)
        if pop.live and self.n > 1 and (ess_threshold is None or ess < ess_threshold * self.n):
            self._resample(lse)

    def _top(self) -> float:
        """The largest weight after the step's observations (NaN if one is NaN)."""
        return float(np.max(self.pop.log_w))

    def _update_live(self) -> None:
        """The particles with zero weight dead, `pop.live` the ones still deriving."""
        self.pop.update_live()

    @property
    def _roulette_rng(self) -> np.random.Generator:
        """The roulette's own random stream (from the run's seed), made when first needed:
        the run's stream is not drawn from (a run changes only once a particle is dropped)."""
        if self._roulette is None:
            seq = np.random.SeedSequence([self.seed, _ROULETTE_STREAM])
            self._roulette = np.random.Generator(np.random.PCG64(seq))
        return self._roulette

    def _step_done(self, drawn: list[int]) -> None:
        state, parts = self.state, self.pop.parts
        state.steps = self.steps
        state.log_likelihood = self.pop.log_lik
        state.drawn = drawn
        state.prims = cast("list[Prim]", [parts[i].last for i in drawn])
        for obs in self.observers:
            obs.step_done(state)

    def _derive(self) -> tuple[list[int], list[int]]:
        """Run the live particles to their next primitive, serving their random choices in
        rounds; returns (particles that drew, particles that ended having drawn nothing)."""
        parts = self.pop.parts
        advance_all = self.deriver.advance_all
        order = self.order
        drawn: list[int] = []
        empty: list[int] = []
        # particles already waiting on a site (from the look-ahead) skip round one
        waiting: dict[int, list[int]] = {}
        run: list[int] = []
        for i in self.pop.live:
            need = parts[i].need
            if need is None:
                run.append(i)
            elif need[0] in waiting:
                waiting[need[0]].append(i)
            else:
                waiting[need[0]] = [i]
        # (site served, its particles) of this round; -1: the particles not waiting
        served: list[tuple[int, list[int]]] = [(-1, run)]
        while True:
            # one deriver call for the round's groups, one after the other
            group = served[0][1] if len(served) == 1 else [i for _, g in served for i in g]
            codes = advance_all([parts[i] for i in group])
            pos = 0
            for a, g in served:
                asked: set[int] = set()  # the sites asked for right after site `a`
                for i in g:
                    code = codes[pos]
                    pos += 1
                    if code == DRAWN:
                        drawn.append(i)
                    elif code == NEED:
                        s = parts[i].need[0]  # type: ignore[index]  # set with NEED
                        asked.add(s)
                        if s in waiting:
                            waiting[s].append(i)
                        else:
                            waiting[s] = [i]
                    else:
                        p = parts[i]
                        p.status = "done" if code == DONE else "limit"
                        if code != DONE:
                            p.limit = "max modules"
                        if p.n_prims == 0:
                            empty.append(i)
                if a >= 0:
                    for s in asked:
                        order.saw(a, s)
            if not waiting:
                return drawn, empty
            # a RoundProposal gets every site no other waiting site leads to in one call
            sites = order.free(waiting) if self.batched else [order.pick(waiting)]
            groups = [sorted(waiting.pop(s)) for s in sites]
            self._serve(sites, groups)
            served = list(zip(sites, groups, strict=True))

    def _serve(self, sites: list[int], groups: list[list[int]]) -> None:
        """Draw the values the particles `groups[j]` wait for at site `sites[j]`: one
        proposal call (propose_rows for a RoundProposal, else propose for one site), then
        the weights (log prior - log q), traces and replay values."""
        program = self.program
        objs = []
        for s in sites:
            if not 0 <= s < len(program.sites):
                raise ProgramError(f"program {program.name} asked for unknown site {s}")
            objs.append(program.sites[s])
        if self.buffers is None:  # no features, no RoundProposal: one site
            self._serve_site(objs[0], groups[0])
            return
        tables = self.round_tables(objs) if self.round_tables is not None else None
        if tables is not None:
            self._serve_kernel(objs, groups, tables)
            return
        rows, idx = self._round_rows(objs, groups)
        x = rows.features
        if x is not None and not self.use_features:  # features for the trace only
            rows = RoundRows(rows.sites, rows.counts, rows.site, rows.args, rows.n_args, None, [])
        if self.batched:
            # self.batched: a RoundProposal (checked once, not per round)
            res = self.proposal.propose_rows(rows, self.rng)  # type: ignore[attr-defined]
            self._weigh(idx, res[:, 1], res[:, 2])
            vals = res[:, 0].tolist()
        else:  # one site, with features (recorded traces)
            vals = self._propose_one(objs[0], rows, idx)
        self._record_round(objs, groups, vals, x)

    def _serve_kernel(
        self, sites: list[Site], groups: list[list[int]], tables: tuple[Any, ...]
    ) -> None:
        """A round whose every site the guide's kernel serves (Guide.round_tables): the
        packed state, features, nets, draws and weights in one kernels.serve_round call;
        the numbers, and the run's random draws, are those of the separate calls."""
        packed, top_k = self._pack(sites, groups)
        buf = self.buffers
        guide: Any = self.proposal  # a Guide (round_tables is its method)
        assert buf is not None and self.fmaker is not None
        m = 0
        for site, g in zip(sites, groups, strict=True):
            if site.index not in self.width_ok:  # once per site and run
                guide.check_width(site, len(g), self.n_feat[site.index] - self.trim)
                self.width_ok.add(site.index)
            m += len(g)
        rng = self.rng
        u = rng.random(m)
        z = rng.standard_normal(m) if guide.needs_normals(sites) else _NO_ROWS
        pop = self.pop
        x = buf.rows(self.fmaker.n_common)
        n, bad = self.kernels.serve_round(
            packed,
            *buf.state(top_k),
            x,
            *self.fmaker.window_args(self.canvas),
            *tables,
            buf.params(guide.widest),
            u,
            z,
            buf.out,
            pop.log_w,
            pop.log_prior,
            self.kernels.NO_MEMO,
            self.kernels.NO_MEMO_KEY,
        )
        if bad >= 0:
            counts = [len(g) for g in groups]
            guide.bad_row(sites, counts, buf.args[:n], buf.n_args[:n], bad)
        feats = x[:n].copy() if self.trace is TraceRecording.FULL else None
        self._record_round(sites, groups, buf.out[:n, 0].tolist(), feats)

    def _record_round(
        self, sites: list[Site], groups: list[list[int]], vals: list[float], x: np.ndarray | None
    ) -> None:
        """`_record` for each site of a round: vals (and x's rows) are its groups' in turn."""
        if len(groups) == 1:
            self._record(sites[0], groups[0], vals, x)
            return
        pos = 0
        for site, g in zip(sites, groups, strict=True):
            m = len(g)
            self._record(site, g, vals[pos : pos + m], None if x is None else x[pos : pos + m])
            pos += m

    def _record(self, site: Site, idx: list[int], vals: list[float], x: np.ndarray | None) -> None:
        """The values (and, for full traces, the feature rows x, cut to the site's width)
        into the particles' replay values and traces; the observers hear of them."""
        feats = None
        if self.trace is TraceRecording.FULL:
            assert x is not None
            feats = x[:, : self.n_feat[site.index]]
        _record(self.pop.parts, site, idx, vals, feats, self.trace)
        for obs in self.observers:
            obs.site_drawn(site, idx, vals)

    def _propose_one(self, site: Site, rows: RoundRows, idx: np.ndarray) -> list[float]:
        """`propose` for the rows of one site (a proposal that is no RoundProposal); weighs
        them and returns the values."""
        args = np.array(rows.args[:, : rows.n_args[0]])
        f = None if rows.features is None else rows.features[:, : rows.widths[0]]
        values, log_q = self.proposal.propose(site, args, f, self.rng)
        values = np.asarray(values, dtype=np.float64)
        log_q = np.asarray(log_q, dtype=np.float64)
        if self.is_prior:  # log q = log prior: the weight does not change
            self._weigh(idx, None, log_q)
        else:
            self._weigh(idx, log_q, prior_logpdf(site, args, values))
        return cast("list[float]", values.tolist())

    def _serve_site(self, site: Site, idx: list[int]) -> None:
        """One site without features (the prior, or a proposal that reads none): its
        prior arguments as one array, one `propose` call."""
        parts = self.pop.parts
        rows = [parts[i].need[1] for i in idx]  # type: ignore[index]  # waiting: set
        args = _prior_args(site, rows)
        if not kind_of(site).weighted and args.shape[1] != site.n_args():
            raise ProgramError(
                f"site {site.id} (line {site.line}): {site.kind} takes "
                f"{site.n_args()} arguments, got {args.shape[1]}"
            )
        values, log_q = self.proposal.propose(site, args, None, self.rng)
        values = np.asarray(values, dtype=np.float64)
        vals = values.tolist()
        ia = np.asarray(idx, dtype=np.intp)
        if self.is_prior:  # log q = log prior: the weight does not change
            self._weigh(ia, None, log_q)
        else:
            log_q = np.asarray(log_q, dtype=np.float64)
            log_p = None
            if kind_of(site).weighted:  # often one weight tuple for all rows: a table
                log_p = _weights_logp(site, rows, args, vals, self.tables)
            if log_p is None:
                log_p = prior_logpdf(site, args, values)
            self._weigh(ia, log_q, log_p)
        self._record(site, idx, vals, None)

    def _weigh(self, idx: np.ndarray, log_q: np.ndarray | None, log_p: np.ndarray) -> None:
        """Particles idx (distinct) drew values: log w += log p - log q (NaN: zero weight;
        log_q None: the prior proposal, no change), log prior += log p. A particle's terms
        are added in the order its sites were served. One kernel call (kernels.add_weights)
        when the run has loaded the kernels; the same arithmetic in numpy in a run that
        needs none (a forward sample: no canvas, no features)."""
        pop = self.pop
        if self.kernels is not None:
            self.kernels.add_weights(
                pop.log_w, pop.log_prior, idx, _NO_ROWS if log_q is None else log_q, log_p
            )
            return
        if log_q is not None:
            with np.errstate(invalid="ignore"):
                delta = log_p - log_q
            pop.log_w[idx] += np.where(np.isnan(delta), -np.inf, delta)
        pop.log_prior[idx] += log_p

    def _round_rows(
        self, sites: list[Site], groups: list[list[int]]
    ) -> tuple[RoundRows, np.ndarray]:
        """The round's rows (and the particle of each): the waiting particles' state
        packed (_pack), unpacked into the run's buffers by one kernel call, and their
        feature rows (one kernel call)."""
        packed, top_k = self._pack(sites, groups)
        return self._unpack(packed, sites, groups, top_k)

    def _pack(self, sites: list[Site], groups: list[list[int]]) -> tuple[np.ndarray, int]:
        """The waiting particles' state packed into one float64 vector in one pass
        (kernels.unpack_round's layout), and the most prior arguments a row has."""
        parts = self.pop.parts
        t_width = self.t_width
        flat: list[Any] = []
        top_k = 0
        for site, g in zip(sites, groups, strict=True):
            p = parts[g[0]]
            a = len(p.stack[0]) - 1  # type: ignore[index]  # waiting: module on top
            k = len(p.need[1])  # type: ignore[index]  # waiting: set
            flat += (site.index, len(g), a, k)
            for i in g:
                p = parts[i]
                top = p.stack  # (module, depth, rest)
                mod = top[0]  # type: ignore[index]  # same
                need = p.need[1]  # type: ignore[index]  # same
                if len(mod) != a + 1 or len(need) != k:
                    _check_rows(site, [parts[j] for j in g])
                flat.append(i)
                flat.append(top[1])  # type: ignore[index]  # same
                flat += p.turtle[:t_width]
                flat += mod[1:]
                flat += need
            if k != site.n_args() and not kind_of(site).weighted:
                raise ProgramError(
                    f"site {site.id} (line {site.line}): {site.kind} takes "
                    f"{site.n_args()} arguments, got {k}"
                )
            top_k = max(top_k, k)
        try:
            packed = np.array(flat, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            for site, g in zip(sites, groups, strict=True):
                _check_rows(site, [parts[i] for i in g])
            raise ProgramError(
                f"program {self.program.name}: a turtle state holds something else than numbers"
            ) from None
        return packed, top_k

    def _unpack(
        self, packed: np.ndarray, sites: list[Site], groups: list[list[int]], top_k: int
    ) -> tuple[RoundRows, np.ndarray]:
        """`_round_rows`' kernel calls: the packed state into the buffers, the features."""
        buf = self.buffers
        assert buf is not None
        n = buf.unpack(packed, top_k)
        idx = buf.idx[:n]
        x = None
        widths = []
        fmaker = self.fmaker
        if fmaker is not None:
            x = fmaker.rows_from(
                self.canvas, idx, buf.turtle[:n], buf.depth[:n], buf.extra[:n], buf.n_extra[:n]
            )
            n_feat, trim = self.n_feat, self.trim
            widths = [n_feat[s.index] - trim for s in sites]
        counts = [len(g) for g in groups]
        rows = RoundRows(sites, counts, buf.site[:n], buf.args[:n], buf.n_args[:n], x, widths)
        return rows, idx

    def _observe(self, drawn: list[int], empty: list[int]) -> None:
        """Rasterize the new primitives and apply the likelihood increments (and the blank
        image's log-likelihood to particles that ended without drawing)."""
        parts = self.pop.parts
        drawn.sort()
        # a particle that drew has its primitive in `last`
        self._observe_prims(drawn, empty, cast("list[Prim]", [parts[i].last for i in drawn]))
        cap = self.cap
        for i in drawn:
            p = parts[i]
            if p.stack is None:
                p.status = "done"
            elif p.n_prims >= cap:
                p.status = "limit"
                p.limit = "max primitives"

    def _observe_prims(
        self,
        drawn: list[int],
        empty: list[int],
        prims: Sequence[Prim],
        packed: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        """Rasterize `prims` (one per particle of `drawn`, ascending; `packed`: the same
        as the draw kernel's codes and parameters) and apply the likelihood increments,
        and the blank image's to the particles of `empty`."""
        pop = self.pop
        if drawn:
            idx = np.asarray(drawn, dtype=np.intp)
            batch: DrawBatch | PrimBatch
            if self.canvas is not None:
                if packed is None:
                    batch = self.canvas.draw(idx, cast("list[Prim]", prims))
                else:
                    batch = self.canvas.draw_packed(idx, *packed)
                batch.prims = cast("list[Prim]", prims)
            else:
                batch = PrimBatch(
                    idx, np.array([prim_bbox(q) for q in prims]), cast("list[Prim]", prims)
                )
            if self.likelihood is not None:
                inc = np.asarray(
                    self.likelihood.increment(self.like_state, self.canvas, batch), dtype=np.float64
                )
                pop.add_loglik(idx, np.where(np.isnan(inc), -np.inf, inc))
        if empty and self.blank_ll is not None:
            pop.add_loglik(np.asarray(empty, dtype=np.intp), np.float64(self.blank_ll))

    def _resample(self, lse: float) -> None:
        """Resample (lse: log sum exp of the weights, from the ESS)."""
        self.log_z += lse - math.log(self.n)
        anc = self._take()
        self.n_resample += 1
        if self.observers:
            take_arrays(self.state.arrays, anc)
            for obs in self.observers:
                obs.resampled(anc)

    def _take(self) -> np.ndarray:
        """The ancestors drawn from the weights; particle k becomes old particle anc[k] in
        the population, the likelihood's state and the canvas. Returns anc."""
        anc = draw_ancestors(self.resample, self.pop.log_w, self.rng)
        self.pop.take(anc)
        take_arrays(self.like_state, anc)
        if self.canvas is not None:
            self.canvas.take(anc)
        return anc

    def _settle(self, finished: list[int]) -> bool:
        """Particles that finished (were live, are not) weighed by the likelihood itself
        rather than its potential (Likelihood.settle); whether a weight changed."""
        if not finished:
            return False
        pop = self.pop
        assert self.likelihood is not None
        idx = np.asarray(finished, dtype=np.intp)
        c = np.asarray(self.likelihood.settle(self.like_state, idx), dtype=np.float64)
        c = np.where(np.isnan(c), -np.inf, c)
        c = np.where(np.isfinite(pop.log_w[idx]), c, 0.0)  # zero weights stay zero
        pop.log_w[idx] += c
        pop.log_lik[idx] += c
        return bool(c.any())

    def stop_live(self, reason: str) -> None:
        """The live particles stop with status "limit" and this reason ("max steps"),
        weighed by the likelihood itself (_settle)."""
        live = list(self.pop.live)
        self._limit_live(reason)
        if self.settles:
            self._settle(live)

    def _limit_live(self, reason: str) -> None:
        """The live particles' status "limit", with this reason."""
        for i in self.pop.live:
            self.pop.parts[i].status = "limit"
            self.pop.parts[i].limit = reason

    def result(self, seconds: float) -> SMCResult:
        pop = self.pop
        log_w = pop.log_w
        finals = [
            FinalParticle(
                primitives=cons_to_list(p.prims),
                log_prior=float(pop.log_prior[i]),
                log_likelihood=float(pop.log_lik[i]),
                log_weight=float(log_w[i]),
                trace=cons_to_list(p.trace) if self.trace is not TraceRecording.NONE else None,
                status=p.status,
                limit=p.limit if p.status == "limit" else None,
            )
            for i, p in enumerate(pop.parts)
        ]
        return self._result(finals, seconds)

    def _result(
        self, finals: list[FinalParticle], seconds: float, info: dict[str, Any] | None = None
    ) -> SMCResult:
        """The SMCResult of the final particles: the best by log prior + log likelihood,
        the evidence, counts (and `info`'s entries)."""
        pop = self.pop
        log_w = pop.log_w
        log_z = self.log_z + _logsumexp(log_w) - math.log(self.n)
        score = np.where(np.isfinite(log_w), pop.log_prior + pop.log_lik, -np.inf)
        status = {k: sum(p.status == k for p in finals) for k in ("done", "limit", "dead")}
        return SMCResult(
            particles=finals,
            log_weights=log_w.copy(),
            best=finals[int(np.argmax(score))],
            log_evidence=float(log_z),
            ess_history=self.ess_history,
            steps=self.steps,
            seconds=seconds,
            info={
                "particle_steps": self.particle_steps,
                "resamples": self.n_resample,
                "status": status,
                "limits": _limit_counts(finals),
                **(info or {}),
            },
        )


class _Buffers:
    """A run's arrays for the rows of its rounds, one row per particle at most, and the
    kernel that fills them (kernels.unpack_round)."""

    def __init__(self, program: Program, n: int, t_width: int) -> None:
        from ngpm_runtime import kernels  # numba loads with the first rows

        self.unpack_round = kernels.unpack_round
        sites = program.sites
        shape = np.array([(int(s.arity), int(s.n_args())) for s in sites], dtype=np.int64)
        shape = shape.reshape(len(sites), 2)  # (arity, prior argument count) per site
        self.shape = shape
        self.t_width = t_width
        self.n = n
        self.idx = np.zeros(n, dtype=np.intp)
        self.site = np.zeros(n, dtype=np.int64)
        self.turtle = np.zeros((n, t_width))
        self.depth = np.zeros(n)
        self.extra = np.zeros((n, int((shape[:, 0] + shape[:, 1]).max(initial=0))))
        self.n_extra = np.zeros(n, dtype=np.int64)
        self.args = np.zeros((n, int(shape[:, 1].max(initial=0))))
        self.n_args = np.zeros(n, dtype=np.int64)
        # kernels.serve_round's feature rows, proposal parameters and (value, log q, log
        # prior) per row
        self.x: np.ndarray | None = None
        self._params = np.zeros((n, 1))
        self.out = np.zeros((n, 3))
        self._state: tuple[Any, ...] | None = None

    def state(self, widest_args: int) -> tuple[Any, ...]:
        """unpack_round's arguments past the packed vector (kernels.serve_round's)."""
        if widest_args > self.args.shape[1]:
            self.args = np.zeros((self.n, widest_args))
            self._state = None
        if self._state is None:
            self._state = (
                self.t_width,
                self.shape,
                self.idx,
                self.site,
                self.turtle,
                self.depth,
                self.extra,
                self.n_extra,
                self.args,
                self.n_args,
            )
        return self._state

    def rows(self, n_common: int) -> np.ndarray:
        """The feature rows' buffer (n, n_common + extra columns) float32."""
        width = n_common + self.extra.shape[1]
        if self.x is None or self.x.shape[1] != width:
            self.x = np.zeros((self.n, width), dtype=np.float32)
        return self.x

    def params(self, widest: int) -> np.ndarray:
        """The proposal parameters' buffer (n, widest) float64."""
        if self._params.shape[1] < widest:
            self._params = np.zeros((self.n, widest))
        return self._params

    def unpack(self, packed: np.ndarray, widest_args: int) -> int:
        """The rows packed in `packed` (kernels.unpack_round's layout) into the buffers;
        returns their count."""
        return int(self.unpack_round(packed, *self.state(widest_args)))


def _check_rows(site: Site, parts: list[Particle]) -> None:
    """The ProgramError for particles waiting on `site` whose prior arguments or module
    parameters are not numbers of one length (nothing if they are)."""
    _prior_args(site, [p.need[1] for p in parts])  # type: ignore[index]  # waiting: set
    params = _rows([p.stack[0][1:] for p in parts])  # type: ignore[index]  # module on top
    if params is None:
        raise ProgramError(f"site {site.id}: modules of different arity share it")


def _record(
    parts: list[Particle],
    site: Site,
    idx: list[int],
    vals: list[float],
    feats: np.ndarray | None,
    trace: TraceRecording,
) -> None:
    """Append the drawn values to the particles' replay values (and traces)."""
    s = site.index
    st = (s,)
    if trace is TraceRecording.FULL:
        assert feats is not None
        for j, i in enumerate(idx):
            p = parts[i]
            p.trace = ((s, feats[j], vals[j]), p.trace)
    elif trace is TraceRecording.VALUES:
        for i, v in zip(idx, vals, strict=True):
            p = parts[i]
            p.trace = ((s, None, v), p.trace)
    cont = kind_of(site).continuous
    for i, v in zip(idx, vals, strict=True):
        p = parts[i]
        p.values += (v,)
        p.sites += st
        p.need = None
        if cont:
            p.cont = True


class SiteOrder:
    """Which waiting site to serve next (greedy batching, one proposal call per round).

    It learns which sites follow which within a step (`saw`) and serves a site that no
    other waiting site leads to, most waiting particles first, lowest index on ties: the
    particles left waiting are often joined by the served ones later in the same step.
    Every round serves one site, so a step always ends; the choice is deterministic."""

    def __init__(self) -> None:
        self.reach: dict[int, set[int]] = {}  # transitive closure of the seen successions

    def saw(self, a: int, b: int) -> None:
        """Site `b` was asked for right after site `a` in a step."""
        ra = self.reach.setdefault(a, set())
        if b in ra:
            return
        new = {b} | self.reach.get(b, set())
        for x, rx in self.reach.items():  # every path into a now goes on to b
            if x == a or a in rx:
                rx |= new

    def _blocked(self, waiting: dict[int, list[int]]) -> set[int]:
        """The waiting sites that another waiting site leads to."""
        keys = waiting.keys()
        blocked: set[int] = set()
        for a in waiting:
            ra = self.reach.get(a)
            if ra:
                hit = ra & keys
                hit.discard(a)  # a site that follows itself does not block itself
                blocked |= hit
        return blocked

    def pick(self, waiting: dict[int, list[int]]) -> int:
        if len(waiting) == 1:
            return next(iter(waiting))
        blocked = self._blocked(waiting)
        first = [k for k in waiting if k not in blocked]
        return max(first or waiting, key=lambda k: (len(waiting[k]), -k))

    def free(self, waiting: dict[int, list[int]]) -> list[int]:
        """Every waiting site that no other waiting site leads to, ascending (no particle
        is expected to join them later in the step); `[pick(waiting)]` when a cycle leaves
        none."""
        if len(waiting) == 1:
            return list(waiting)
        blocked = self._blocked(waiting)
        first = sorted(k for k in waiting if k not in blocked)
        return first or [self.pick(waiting)]


def _weights_logp(
    site: Site,
    rows: list[Args],
    args: np.ndarray,
    vals: list[float],
    tables: dict[tuple[int, Args], list[float]],
) -> np.ndarray | None:
    """prior_logpdf of the values of a weighted site (categorical) whose rows share one
    weight tuple, from a table
    made by prior_logpdf itself (the same numbers); None when it does not apply."""
    first = rows[0]
    for r in rows:
        if r != first:
            return None
    key = (site.index, first)
    table = tables.get(key)
    if table is None:
        k = len(first)
        table = prior_logpdf(
            site, np.repeat(args[:1], k, axis=0), np.arange(k, dtype=np.float64)
        ).tolist()
        if len(tables) >= 4096:
            tables.clear()
        tables[key] = table
    k = len(table)
    out = []
    for v in vals:
        i = int(v) if v == v and abs(v) < 1e18 else -1
        if i != v or not 0 <= i < k:
            return None
        out.append(table[i])
    return np.array(out)


_NO_ROWS = np.zeros(0)
# _rows of one shared tuple, by (tuple, n): read-only arrays, reused across rounds and runs
_SHARED: dict[tuple[Args, int], np.ndarray] = {}


def _rows(rows: list[Args]) -> np.ndarray | None:
    """(n, k) float64 from n tuples of k numbers (often one shared tuple: then a read-only
    array remembered in _SHARED, unless the tuple holds a zero, whose sign a look-up by
    equality could change); None if ragged."""
    first = rows[0]
    k = len(first)
    n = len(rows)
    try:
        if all(r is first for r in rows):
            key = (first, n)
            try:
                out = _SHARED.get(key)
                keep = out is None and 0.0 not in first
            except TypeError:  # an unhashable entry
                out, keep = None, False
            if out is None:
                out = np.repeat(np.array(first, dtype=np.float64).reshape(1, k), n, axis=0)
                if keep:
                    if len(_SHARED) >= 4096:
                        _SHARED.clear()
                    out.flags.writeable = False
                    _SHARED[key] = out
            return out
        if all(len(r) == k for r in rows):
            return np.fromiter(chain.from_iterable(rows), np.float64, n * k).reshape(n, k)
    except (TypeError, ValueError):
        pass
    return None


def _prior_args(site: Site, rows: list[Args]) -> np.ndarray:
    args = _rows(rows)
    if args is None:
        raise ProgramError(
            f"site {site.id} (line {site.line}): prior arguments are not numbers of one length"
        )
    return args


def _take_particles(parts: list[Particle], anc: np.ndarray) -> tuple[list[Particle], list[int]]:
    """Particles for the ancestor indices (ascending), and the live ones' new indices:
    duplicates of live particles are shallow copies; finished ones never change, so they
    are shared."""
    out: list[Particle] = []
    live: list[int] = []
    prev = -1
    for k, a in enumerate(anc.tolist()):
        p = parts[a]
        if p.status == "live":
            if a == prev:
                p = p.copy()
            live.append(k)
        out.append(p)
        prev = a
    return out, live


def check_run_options(n_particles: object, seed: object, max_modules: object) -> None:
    """SMCOptionError for a particle count, seed or module cap that is not a fitting integer."""
    if isinstance(n_particles, bool) or not isinstance(n_particles, int | np.integer):
        raise SMCOptionError(f"the particle count must be an integer, got {n_particles!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise SMCOptionError(f"the seed must be a non-negative integer, got {seed!r}")
    if max_modules is not None and (
        not isinstance(max_modules, int | np.integer)
        or isinstance(max_modules, bool)
        or max_modules < 1
    ):
        raise SMCOptionError(f"max_modules must be an integer >= 1, got {max_modules!r}")


def start_particles(
    deriver: Deriver, program: Program, start: Sequence[float] | None, n: int
) -> list[Particle]:
    """n new particles at the start pose (x, y, heading), default the program's; a 3D
    program's may be (x, y, z, heading)."""
    pose = tuple(program.start if start is None else start)
    if len(pose) != (4 if program.dim == 3 and len(pose) == 4 else 3):
        raise SMCOptionError(f"start must be (x, y, heading) or, in 3D, (x, y, z, heading): {pose}")
    turtle = (float(pose[0]), float(pose[1]), float(pose[-1]), 1.0)
    parts = [deriver.start(turtle) for _ in range(n)]
    if len(pose) == 4:  # the 3D turtle starts at z = 0: move it
        for p in parts:
            p.turtle = (p.turtle[0], p.turtle[1], float(pose[2])) + p.turtle[3:]
    return parts


def module_cap(program: Program, max_modules: int | None = None) -> int:
    """The "max modules" cap of a run: the option, else the grammar's, else the default."""
    if max_modules is not None:
        return int(max_modules)
    return int(program.max_modules) if program.max_modules else DEFAULT_MAX_MODULES


def _limit_counts(finals: list[FinalParticle]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for p in finals:
        if p.limit:
            counts[p.limit] = counts.get(p.limit, 0) + 1
    return counts
