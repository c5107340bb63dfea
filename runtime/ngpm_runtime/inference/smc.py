"""Sequential Monte Carlo over a compiled program (architecture.md sections 2, 3, 5, 8).

All particles advance together. In one step every live particle runs to its next drawn
primitive; the random values it asks for on the way are drawn in rounds, one batched
`proposal.propose` call per round for the particles waiting on one site (`SiteOrder` picks
it; particles by index). Then the new primitives are rasterized, the likelihood increments
applied and, every step or when the ESS drops below `ess_threshold * N`, the particles are
resampled. Weights carry
`log prior - log q` of every site, so any proposal gives a correct answer.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from itertools import chain
from typing import Any

import numpy as np

from ngpm_runtime.errors import NgpmError, ProgramError, SMCFailed
from ngpm_runtime.geometry.derive import DEFAULT_MAX_MODULES, DONE, DRAWN, NEED, Deriver, Particle
from ngpm_runtime.geometry.turtle import cons_to_list, prim_bbox
from ngpm_runtime.inference.distributions import prior_logpdf
from ngpm_runtime.inference.proposals import PriorProposal
from ngpm_runtime.inference.resample import SCHEMES
from ngpm_runtime.inference.resample import resample as draw_ancestors
from ngpm_runtime.program import Program


class SMCOptionError(NgpmError):
    """An SMC option has a value that cannot be used."""


@dataclass
class FinalParticle:
    primitives: list[tuple]
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


@dataclass
class PrimBatch:
    """What a likelihood sees when the run has no canvas: who drew what."""

    idx: np.ndarray
    bbox: np.ndarray
    prims: list[tuple]


def _logsumexp(a: np.ndarray) -> float:
    m = float(np.max(a))
    if not math.isfinite(m):
        return m
    return m + math.log(float(np.sum(np.exp(a - m))))


def _ess(log_w: np.ndarray) -> float:
    lse = _logsumexp(log_w)
    if not math.isfinite(lse):
        return 0.0
    return float(math.exp(2.0 * lse - _logsumexp(2.0 * log_w)))


def forward(
    program: Program, seed: int = 0, start: tuple[float, float, float] | None = None,
    max_modules: int | None = None,
) -> FinalParticle:
    """One prior sample of the program: SMC with one particle and no likelihood."""
    return smc(program, None, 1, seed=seed, start=start, max_modules=max_modules).particles[0]


def smc(
    program: Program,
    likelihood: Any,
    n_particles: int,
    proposal: Any = None,
    seed: int = 0,
    resample: str = "residual",
    ess_threshold: float | None = None,
    record_trace: bool | str = False,
    start: tuple[float, float, float] | None = None,
    canvas_size: tuple[int, int] = (50, 50),
    target_mask: np.ndarray | None = None,
    max_steps: int | None = None,
    max_primitives: int | None = None,
    max_modules: int | None = None,
) -> SMCResult:
    """Run SMC; `likelihood=None` (or a NullLikelihood) means no likelihood, no canvas.

    A likelihood with `needs_canvas = False` gets, instead of raster's DrawBatch, a
    `PrimBatch` (idx, bbox, prims); with a canvas, the DrawBatch also carries `.prims`.

    `ess_threshold` is a fraction of N: resample only when ESS < ess_threshold * N
    (None: every step). `max_primitives` overrides `program.max_primitives`, `max_modules`
    `program.max_modules` (modules one particle may expand or interpret in one step).
    `record_trace=True` records every particle's trace with features; `"values"` records
    (site, None, value) only, at no feature cost (`replay` adds the features afterwards).
    """
    t0 = time.perf_counter()
    check_run_options(n_particles, seed, max_modules)
    n = int(n_particles)
    if n < 1:
        raise SMCOptionError(f"need at least one particle, got {n_particles}")
    if resample not in SCHEMES:
        raise SMCOptionError(f"unknown resampling scheme {resample!r} "
                             f"(choose from {', '.join(SCHEMES)})")
    if record_trace not in (False, True, "values"):
        raise SMCOptionError(f"record_trace must be True, False or 'values', "
                             f"got {record_trace!r}")
    if ess_threshold is not None and not 0.0 < ess_threshold <= 1.0:
        raise SMCOptionError(f"ess_threshold must be in (0, 1], got {ess_threshold}")
    if target_mask is not None and tuple(np.shape(target_mask)) != tuple(canvas_size):
        raise SMCOptionError(f"target mask {tuple(np.shape(target_mask))} and canvas size "
                             f"{tuple(canvas_size)} differ")
    rng = np.random.Generator(np.random.PCG64(seed))
    proposal = PriorProposal() if proposal is None else proposal
    is_prior = type(proposal) is PriorProposal
    cap = program.max_primitives if max_primitives is None else int(max_primitives)
    viewport = program.viewport

    # What the run needs: features, a canvas.
    use_features = bool(getattr(proposal, "uses_features", False))
    need_features = use_features or record_trace is True
    if likelihood is not None and _is_null(likelihood):
        likelihood = None  # nothing to compute, no canvas needed
    like_canvas = likelihood is not None and getattr(likelihood, "needs_canvas", True)
    canvas = None
    if need_features or like_canvas:
        if viewport is None:
            raise ProgramError(f"program {program.name} has no viewport: "
                               "cannot rasterize for the likelihood or features")
        from ngpm_runtime.image.raster import Canvas

        canvas = Canvas(n, int(canvas_size[0]), int(canvas_size[1]), viewport)
    fmaker = None
    if need_features:
        from ngpm_runtime.image.features import FeatureMaker

        fmaker = FeatureMaker(program, viewport, target_mask)
    like_state = likelihood.start(n) if likelihood is not None else {}
    blank_ll = _blank_loglik(likelihood, canvas)

    x0, y0, h0 = program.start if start is None else start
    deriver = Deriver(program, max_ops=module_cap(program, max_modules))
    advance = deriver.advance
    parts: list[Particle] = [deriver.start((float(x0), float(y0), float(h0), 1.0))
                             for _ in range(n)]
    log_w = np.zeros(n)
    log_prior = np.zeros(n)
    log_lik = np.zeros(n)
    log_z = 0.0
    ess_history: list[float] = []
    steps = 0
    n_resample = 0
    particle_steps = 0
    live = list(range(n))
    order = SiteOrder()
    tables: dict[tuple, np.ndarray] = {}  # categorical log prior per (site, weights)

    while live:
        if max_steps is not None and steps >= max_steps:
            for i in live:
                parts[i].status = "limit"
                parts[i].limit = "max steps"
            break
        steps += 1
        particle_steps += len(live)
        drawn: list[int] = []
        empty: list[int] = []  # particles that ended without drawing anything
        # particles already waiting on a site (from the look-ahead below) skip round one
        waiting: dict[int, list[int]] = {}
        run = []
        for i in live:
            need = parts[i].need
            if need is None:
                run.append(i)
            elif need[0] in waiting:
                waiting[need[0]].append(i)
            else:
                waiting[need[0]] = [i]
        served = -1  # the site `run` was just served at (-1: none)
        nexts: set[int] = set()  # the sites the particles of `run` asked for next
        while run or waiting:
            for i in run:
                p = parts[i]
                code = advance(p)
                if code == DRAWN:
                    drawn.append(i)
                elif code == NEED:
                    s = p.need[0]
                    nexts.add(s)
                    if s in waiting:
                        waiting[s].append(i)
                    else:
                        waiting[s] = [i]
                else:
                    p.status = "done" if code == DONE else "limit"
                    if code != DONE:
                        p.limit = "max modules"
                    if p.n_prims == 0:
                        empty.append(i)
            if served >= 0:
                for s in nexts:
                    order.saw(served, s)
            nexts.clear()
            if not waiting:
                break
            served = order.pick(waiting)
            run = sorted(waiting.pop(served))
            _serve_site(program, served, run, parts, proposal, is_prior, rng, log_w,
                        log_prior, fmaker, canvas, use_features, record_trace, tables)

        if drawn:
            drawn.sort()
            idx = np.asarray(drawn, dtype=np.intp)
            prims = [parts[i].last for i in drawn]
            if canvas is not None:
                batch = canvas.draw(idx, prims)
                try:
                    batch.prims = prims
                except AttributeError:
                    pass
            else:
                batch = PrimBatch(idx, np.array([prim_bbox(q) for q in prims]), prims)
            if likelihood is not None:
                inc = np.asarray(likelihood.increment(like_state, canvas, batch),
                                 dtype=np.float64)
                inc = np.where(np.isnan(inc), -np.inf, inc)
                log_w[idx] += inc
                log_lik[idx] += inc
            for i in drawn:
                p = parts[i]
                if p.stack is None:
                    p.status = "done"
                elif p.n_prims >= cap:
                    p.status = "limit"
                    p.limit = "max primitives"

        if empty and blank_ll is not None:
            ia = np.asarray(empty, dtype=np.intp)
            log_w[ia] += blank_ll
            log_lik[ia] += blank_ll

        if (log_w == np.inf).any():
            raise SMCFailed(f"a weight became +inf at step {steps} (program {program.name}): "
                            "a proposal gave zero density to its own value or a likelihood "
                            "returned +inf")
        if not np.isfinite(log_w).any():
            raise SMCFailed(f"every particle's weight is zero after step {steps} "
                            f"({n} particles, program {program.name})")
        for i in np.flatnonzero(log_w == -np.inf).tolist():
            if parts[i].status == "live":
                parts[i].status = "dead"
        live = [i for i in live if parts[i].status == "live"]
        ess = _ess(log_w)
        ess_history.append(ess)
        if live and n > 1 and (ess_threshold is None or ess < ess_threshold * n):
            log_z += _logsumexp(log_w) - math.log(n)
            anc = draw_ancestors(resample, log_w, rng)
            parts = _take_particles(parts, anc)
            log_prior = log_prior[anc]
            log_lik = log_lik[anc]
            log_w = np.zeros(n)
            for key in like_state:
                like_state[key] = like_state[key][anc]
            if canvas is not None:
                canvas.take(anc)
            live = [i for i in range(n) if parts[i].status == "live"]
            n_resample += 1

    log_z += _logsumexp(log_w) - math.log(n)
    finals = [
        FinalParticle(
            primitives=cons_to_list(p.prims),
            log_prior=float(log_prior[i]),
            log_likelihood=float(log_lik[i]),
            log_weight=float(log_w[i]),
            trace=cons_to_list(p.trace) if record_trace is not False else None,
            status=p.status,
            limit=p.limit if p.status == "limit" else None,
        )
        for i, p in enumerate(parts)
    ]
    score = np.where(np.isfinite(log_w), log_prior + log_lik, -np.inf)
    best = finals[int(np.argmax(score))]
    return SMCResult(
        particles=finals,
        log_weights=log_w.copy(),
        best=best,
        log_evidence=float(log_z),
        ess_history=ess_history,
        steps=steps,
        seconds=time.perf_counter() - t0,
        info={"particle_steps": particle_steps, "resamples": n_resample,
              "status": {k: sum(p.status == k for p in finals) for k in ("done", "limit", "dead")},
              "limits": _limit_counts(finals)},
    )



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

    def pick(self, waiting: dict[int, list[int]]) -> int:
        if len(waiting) == 1:
            return next(iter(waiting))
        keys = waiting.keys()
        blocked: set[int] = set()
        for a in waiting:
            ra = self.reach.get(a)
            if ra:
                hit = ra & keys
                hit.discard(a)  # a site that follows itself does not block itself
                blocked |= hit
        first = [k for k in waiting if k not in blocked]
        return max(first or waiting, key=lambda k: (len(waiting[k]), -k))


def replay(
    program: Program,
    values: list[tuple[int, float]],
    start: tuple[float, float, float] | None = None,
    canvas_size: tuple[int, int] = (50, 50),
    target_mask: np.ndarray | None = None,
    max_primitives: int | None = None,
    max_modules: int | None = None,
) -> FinalParticle:
    """The one derivation that makes the given (site, value) choices, with its full trace
    (features as `smc(..., record_trace=True)` computes them); no likelihood."""
    from ngpm_runtime.inference.proposals import ReplayProposal

    proposal = ReplayProposal(values)
    res = smc(program, None, 1, proposal=proposal, record_trace=True, start=start,
              canvas_size=canvas_size, target_mask=target_mask,
              max_primitives=max_primitives, max_modules=max_modules)
    proposal.check_used()
    return res.particles[0]


def _blank_loglik(likelihood: Any, canvas: Any) -> float | None:
    """Log-likelihood of an empty drawing, charged to particles that end without drawing
    (increments only come with primitives); None when the likelihood cannot say."""
    full = getattr(likelihood, "full", None)
    if full is None or canvas is None:
        return None
    blank = np.zeros(canvas.image.shape[1:], dtype=np.uint8)
    value = float(full(blank, np.array([np.inf, np.inf, -np.inf, -np.inf])))
    return value if not math.isnan(value) else -math.inf


def _is_null(likelihood: Any) -> bool:
    from ngpm_runtime.inference.likelihood import NullLikelihood

    return isinstance(likelihood, NullLikelihood)


def _serve_site(
    program: Program,
    s: int,
    idx: list[int],
    parts: list[Particle],
    proposal: Any,
    is_prior: bool,
    rng: np.random.Generator,
    log_w: np.ndarray,
    log_prior: np.ndarray,
    fmaker: Any,
    canvas: Any,
    use_features: bool,
    record_trace: bool | str,
    tables: dict[tuple, np.ndarray],
) -> None:
    """Draw site `s` for the waiting particles `idx` with one proposal call."""
    if not 0 <= s < len(program.sites):
        raise ProgramError(f"program {program.name} asked for unknown site {s}")
    site = program.sites[s]
    rows = [parts[i].need[1] for i in idx]
    args = _prior_args(site, rows)
    if site.kind != "categorical" and args.shape[1] != site.n_args():
        raise ProgramError(f"site {site.id} (line {site.line}): {site.kind} takes "
                           f"{site.n_args()} arguments, got {args.shape[1]}")
    feats = None
    if fmaker is not None:
        feats = _features(fmaker, site, canvas, idx, parts, args)
    values, log_q = proposal.propose(site, args, feats if use_features else None, rng)
    ia = np.asarray(idx, dtype=np.intp)
    if is_prior:  # log q = log prior: the weight does not change
        log_prior[ia] += log_q
    else:
        values = np.asarray(values, dtype=np.float64)
        log_q = np.asarray(log_q, dtype=np.float64)
        log_p = None
        if site.kind == "categorical":
            log_p = _categorical_logp(site, rows, args, values, tables)
        if log_p is None:
            log_p = prior_logpdf(site, args, values)
        with np.errstate(invalid="ignore"):
            delta = log_p - log_q
        log_w[ia] += np.where(np.isnan(delta), -np.inf, delta)
        log_prior[ia] += log_p
    vals = values.tolist()
    cont = site.kind == "normal" or site.kind == "uniform"
    st = (s,)
    if record_trace is True:
        for j, i in enumerate(idx):
            p = parts[i]
            p.trace = ((s, feats[j], vals[j]), p.trace)
    elif record_trace:
        for i, v in zip(idx, vals, strict=True):
            p = parts[i]
            p.trace = ((s, None, v), p.trace)
    for i, v in zip(idx, vals, strict=True):
        p = parts[i]
        p.values += (v,)
        p.sites += st
        p.need = None
        if cont:
            p.cont = True


def _categorical_logp(site: Any, rows: list[tuple], args: np.ndarray, values: np.ndarray,
                      tables: dict[tuple, np.ndarray]) -> np.ndarray | None:
    """prior_logpdf of categorical values whose rows share one weight tuple, from a table
    made by prior_logpdf itself (the same numbers); None when it does not apply."""
    first = rows[0]
    for r in rows:
        if r != first:
            return None
    key = (site.index, first)
    table = tables.get(key)
    if table is None:
        k = len(first)
        table = prior_logpdf(site, np.repeat(args[:1], k, axis=0), np.arange(k, dtype=np.float64))
        if len(tables) >= 4096:
            tables.clear()
        tables[key] = table
    ki = values.astype(np.intp)
    if not ((ki == values).all() and (ki >= 0).all() and (ki < len(table)).all()):
        return None
    return table[ki]


def _rows(rows: list[tuple]) -> np.ndarray | None:
    """(n, k) float64 from n tuples of k numbers (often one shared tuple); None if ragged."""
    first = rows[0]
    k = len(first)
    n = len(rows)
    try:
        if all(r is first for r in rows):
            return np.repeat(np.array(first, dtype=np.float64).reshape(1, k), n, axis=0)
        if all(len(r) == k for r in rows):
            return np.fromiter(chain.from_iterable(rows), np.float64, n * k).reshape(n, k)
    except (TypeError, ValueError):
        pass
    return None


def _prior_args(site: Any, rows: list[tuple]) -> np.ndarray:
    args = _rows(rows)
    if args is None:
        raise ProgramError(f"site {site.id} (line {site.line}): prior arguments are not "
                           "numbers of one length")
    return args


def _features(fmaker: Any, site: Any, canvas: Any, idx: list[int], parts: list[Particle],
              args: np.ndarray) -> np.ndarray:
    n = len(idx)
    turtle = np.fromiter(chain.from_iterable(parts[i].turtle for i in idx), np.float64,
                         4 * n).reshape(n, 4)
    tops = [parts[i].stack for i in idx]
    depth = np.fromiter((t[1] for t in tops), np.float64, n)
    np.maximum(depth, 0.0, out=depth)  # the axiom pseudo-module has depth -1
    params = _rows([t[0][1:] for t in tops])
    if params is None:
        raise ProgramError(f"site {site.id}: modules of different arity share it")
    return fmaker.features(site, canvas, np.asarray(idx, dtype=np.intp), turtle, depth,
                           params, args)


def _take_particles(parts: list[Particle], anc: np.ndarray) -> list[Particle]:
    """Particles for the ancestor indices (ascending): duplicates of live particles are
    shallow copies; finished ones never change, so they are shared."""
    out: list[Particle] = []
    prev = -1
    for a in anc.tolist():
        p = parts[a]
        out.append(p.copy() if a == prev and p.status == "live" else p)
        prev = a
    return out


def check_run_options(n_particles: Any, seed: Any, max_modules: Any) -> None:
    """SMCOptionError for a particle count, seed or module cap that is not a fitting integer."""
    if isinstance(n_particles, bool) or not isinstance(n_particles, int | np.integer):
        raise SMCOptionError(f"the particle count must be an integer, got {n_particles!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise SMCOptionError(f"the seed must be a non-negative integer, got {seed!r}")
    if max_modules is not None and (not isinstance(max_modules, int | np.integer)
                                    or isinstance(max_modules, bool) or max_modules < 1):
        raise SMCOptionError(f"max_modules must be an integer >= 1, got {max_modules!r}")


def module_cap(program: Program, max_modules: int | None = None) -> int:
    """The "max modules" cap of a run: the option, else the grammar's, else the default."""
    if max_modules is not None:
        return int(max_modules)
    own = getattr(program, "max_modules", None)
    return int(own) if own else DEFAULT_MAX_MODULES


def _limit_counts(finals: list[FinalParticle]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for p in finals:
        if p.limit:
            counts[p.limit] = counts.get(p.limit, 0) + 1
    return counts
