"""SMC on the compiled deriver (issue #22): the population as arrays.

`CompiledRun` is run._Run with the particles' derivation state in arrays (module stacks,
turtles, turtle stacks, replay values, requests) that geometry/compiled.py's `advance`
kernel steps, all particles of a round in one call, and a step's rounds in one call of
round_kernels.py's prior_derive or guided_derive. Everything else is _Run's: rounds served
in SiteOrder's order, the proposal's draws from the run's generator, weights, likelihood,
resampling. So a seeded run draws the same values
and gives the same particles, weights, traces and images as the Python deriver's run, bit
for bit (tests/runtime/inference/test_compiled_run.py).

A replay (smc.replay, one particle, feature traces) has its recorded values served by the
kernel itself, request after request, and the visits' feature rows made once per step
(_replayed): a round per site visit only where the kernel cannot serve one.

`smc()` uses it where `smc._compiled_deriver` finds a compiled deriver (the prior, a guide
whose kernel serves every site, feature traces of a proposal that is no RoundProposal);
when the kernel raises (a math domain error, a runaway grammar), `smc()` runs the Python
deriver instead, which reports the error.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from itertools import repeat
from typing import Any, overload

import numpy as np

from ngpm_runtime.geometry.compiled import CompiledDeriver, forget
from ngpm_runtime.geometry.derive import MAX_PRIMITIVES, MAX_WORK
from ngpm_runtime.geometry.turtle import Prim
from ngpm_runtime.inference.likelihood import CircuitLikelihood, ShapeLikelihood
from ngpm_runtime.inference.proposals import ReplayProposal, RoundRows
from ngpm_runtime.inference.resample import ancestor_counts
from ngpm_runtime.inference.run import (
    FinalParticle,
    Population,
    SMCResult,
    TraceRecording,
    _Buffers,
    _Run,
    start_particles,
    take_arrays,
)
from ngpm_runtime.inference.sitekinds import KINDS
from ngpm_runtime.native_call import generator_addresses

LIVE, FINISHED, LIMITED, DEAD = 0, 1, 2, 3
# of the deriver's arrays _take resamples (take_particles' order), the ones that grow:
# stack, turtle stack, replay values
_GROWING = (0, 3, 5)
STATUS = ("live", "done", "limit", "dead")
LIMITS = (None, "max modules", "max primitives", "max steps")
_PRIM_KINDS = ("seg", "disk", "leaf")
_NO_GAIN = np.zeros(0)
# CompiledRun._pool_args: primitives, their parameters, stack pointers, primitive counts,
# the cap, status, limit; the pool's heads, links, rows and top
_A = np.ndarray
_PoolArgs = tuple[_A, _A, _A, _A, int, _A, _A, _A, _A, _A, int]
# resample_rows' canvas arguments for a run without one (Canvas's dtypes)
_NO_IMAGE: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] = (
    np.zeros((0, 0), dtype=np.uint8),
    np.zeros((0, 0), dtype=np.float32),
    np.zeros((0, 0), dtype=np.uint8),
    np.zeros((0, 0), dtype=np.float32),
)


class KernelFailed(Exception):
    """The compiled deriver raised: the run is done again by the Python deriver."""


class RowPopulation(Population):
    """Population whose particles are rows of arrays: `status` and `limit` per row."""

    def __init__(self, n: int) -> None:
        super().__init__([])
        self.n = n
        self.log_w = np.zeros(n)
        self.log_prior = np.zeros(n)
        self.log_lik = np.zeros(n)
        self.live = list(range(n))
        self.status = np.zeros(n, dtype=np.int8)
        self.limit = np.zeros(n, dtype=np.int8)

    def update_live(self) -> None:
        status = self.status
        status[(self.log_w == -np.inf) & (status == LIVE)] = DEAD
        self.live = np.flatnonzero(status == LIVE).tolist()

    def took(self, arrays: tuple[np.ndarray, ...], live: list[int]) -> None:
        """After resampling (CompiledRun._take): the new status, limit, log prior and log
        likelihood rows and live particles; weights reset to 0."""
        self.status, self.limit, self.log_prior, self.log_lik = arrays
        self.live = live
        self.log_w = np.zeros(self.n)

    def stop_live(self, reason: int) -> None:
        for i in self.live:
            self.status[i] = LIMITED
            self.limit[i] = reason


class CompiledRun(_Run):
    """_Run with the derivation in the compiled deriver's arrays (see the module's doc)."""

    def __init__(self, deriver: CompiledDeriver, *args: Any) -> None:
        super().__init__(*args)
        n = self.n
        info = deriver.info
        self.deriver_c = deriver
        sites = self.program.sites
        m = max(len(sites), 1)
        self.reach = np.zeros((m, m), dtype=np.bool_)  # SiteOrder's closure
        self.site_kind = np.array([KINDS[s.kind].code for s in sites] or [0], dtype=np.int64)
        self.prior_normals = np.array(
            [KINDS[s.kind].prior_normals for s in sites] or [False], dtype=np.bool_
        )
        self.addr = -1  # the grammar's `advance`'s machine-code address (_address)
        self.rng_at = generator_addresses(self.rng)  # the step kernels' generator
        self.wait_ids = np.zeros((m, n), dtype=np.int64)  # a round's waiting particles
        self.wait_n = np.zeros(m, dtype=np.int64)
        self.drawn = np.zeros(n, dtype=np.int64)
        self.empty = np.zeros(n, dtype=np.int64)
        self.counts = np.zeros(3, dtype=np.int64)  # drawn, empty, values recorded
        guided = not self.is_prior and self.trace is not TraceRecording.FULL
        self.guided_tables = self._guided_tables() if guided else ()
        record = self.trace is TraceRecording.VALUES
        self.rec = np.zeros((256, 3) if record else (0, 0))  # (particle, site, value)
        self.max_succ = info.max_succ
        assert isinstance(self.pop, RowPopulation)  # _population's
        self.rows = self.pop
        self.step_prims = PrimRows(np.zeros(0, dtype=np.int64), np.zeros((0, 5)))
        self.stack = np.zeros((n, 64, info.width))
        self.stack[:, 0, 1] = -1.0  # the axiom's pseudo-module at depth -1
        self.sp = np.ones(n, dtype=np.int64)
        self.turtle = np.tile(np.asarray(self.start_pose, dtype=np.float64), (n, 1))
        self.tstack = np.zeros((n, 16, 4))
        self.tsp = np.zeros(n, dtype=np.int64)
        self.vals = np.zeros((n, 8))
        self.nv = np.zeros(n, dtype=np.int64)
        self.need = np.zeros((n, 2 + info.max_args))
        self.need[:, 0] = -1.0
        self.prim = np.zeros(n, dtype=np.int64)
        self.prim_par = np.zeros((n, 5))
        self.n_prims = np.zeros(n, dtype=np.int64)
        self.work = np.zeros(n, dtype=np.int64)
        self.resume = np.zeros((n, 2), dtype=np.int64)
        self.prim_pool = _Pool(n, 6)  # kind code, 5 parameters
        self.trace_pool = _Pool(n, 3)  # site, value, feature row (index into `features`)
        self.features: list[np.ndarray] = []  # feature traces' rows
        self.dlen = int(self.program.derivation_length)
        self.angle = float(self.program.angle)
        self.max_modules = int(self.deriver.max_modules)
        # a replay's recorded values, served in the kernel (see _replayed); empty: none
        self.rsite = np.zeros(0, dtype=np.int64)
        self.rval = np.zeros(0)
        # the next value, the log's floats used, the turtle's width, the most prior arguments
        self.rep = np.array([0, 0, self.t_width, 0], dtype=np.int64)
        self.log = np.zeros(0)
        self.replay_from = self.replay_at = -1
        self.replay_buf: _Buffers | None = None
        self.spare: tuple[np.ndarray, ...] | None = None  # _take's other arrays
        self.fused = self._fused_observe()
        self.live_ids = np.zeros(n, dtype=np.int64)
        self.top_w = 0.0
        self.replay: ReplayProposal | None = None
        if isinstance(self.proposal, ReplayProposal) and n == 1 and self.fmaker is not None:
            self.replay = self.proposal
            values = self.replay.values
            self.rsite = np.array([s for s, _ in values], dtype=np.int64)
            self.rval = np.array([v for _, v in values], dtype=np.float64)
            self.rep[0] = self.replay_from = self.replay_at = self.replay.pos
            self.log = np.zeros(4096)

    def _population(self, start: Sequence[float] | None, n: int) -> Population:
        """A RowPopulation of n particles; the start pose is the Python deriver's first
        particle's (start_particles of one)."""
        self.start_pose = start_particles(self.deriver, self.program, start, 1)[0].turtle
        return RowPopulation(n)

    # ---- derivation ----------------------------------------------------------------------

    def _deriver_state(self) -> tuple[Any, ...]:
        """The arrays and numbers round_kernels.advance_at passes on to the grammar's
        `advance`, in its order, after (ids, codes)."""
        return (
            self.stack,
            self.sp,
            self.turtle,
            self.tstack,
            self.tsp,
            self.vals,
            self.nv,
            self.need,
            self.prim,
            self.prim_par,
            self.n_prims,
            self.work,
            self.resume,
            self.dlen,
            self.angle,
            self.max_modules,
            MAX_WORK,
            MAX_PRIMITIVES,
            self.max_succ,
            self.rsite,
            self.rval,
            self.rep,
            self.log,
        )

    def _step_state(self) -> tuple[Any, ...]:
        """The step kernels' (prior_derive, guided_derive) first arguments: the address of
        `advance`, the run's generator, the live particles, the deriver's state
        (_deriver_state) and the rounds' bookkeeping (waiting lists, outcomes, statuses,
        SiteOrder's closure)."""
        rows = self.rows
        return (
            self._address(),
            self.rng_at,
            np.asarray(rows.live, dtype=np.int64),
            *self._deriver_state(),
            self.wait_ids,
            self.wait_n,
            self.drawn,
            self.empty,
            self.counts,
            rows.status,
            rows.limit,
            self.reach,
        )

    def _address(self) -> int:
        """The machine-code address of the grammar's `advance` for this run's arrays
        (native_call.native_address; compiled or loaded once per process)."""
        if self.addr < 0:
            st = self._deriver_state()
            ids = np.zeros(1, dtype=np.int64)
            args = (ids, *st[:13], ids, *st[13:18], *st[19:])  # advance's own order
            self.addr = self._kernel(self.deriver_c.address, args)
        return self.addr

    def _kernel(self, fn: Callable[..., Any], *args: Any) -> Any:
        """fn(*args), a kernel that runs the grammar's `advance`: KernelFailed when it
        raises (the Python deriver runs the run again and says what)."""
        try:
            return fn(*args)
        except Exception as err:  # numba's errors: the Python deriver says what
            if "numba" in type(err).__module__:  # it did not compile: not again
                forget(self.program)
            if self.replay is not None:  # the Python deriver replays from the start
                self.replay.pos = self.replay_from
            raise KernelFailed(str(err)) from None

    def _advance(self, ids: np.ndarray) -> np.ndarray:
        """The grammar's `advance` over particles ids (round_kernels.advance_at): their
        outcomes."""
        from ngpm_runtime import round_kernels

        codes = np.zeros(len(ids), dtype=np.int64)
        self.stack, self.tstack = self._kernel(
            round_kernels.advance_at, self._address(), ids, codes, *self._deriver_state()
        )
        return codes

    def _start(self) -> np.ndarray:
        """A step's first round: the live particles not waiting (round_kernels.start_rounds;
        the waiting ones into the waiting lists), in a replay all of them (the kernel
        serves the waiting one); the counts reset."""
        from ngpm_runtime import round_kernels

        self.counts[:] = 0
        live = np.asarray(self.rows.live, dtype=np.int64)
        if self.replay is not None:
            self.wait_n[:] = 0
            return live
        return round_kernels.start_rounds(live, self.need, self.wait_ids, self.wait_n)

    def _pick(self, group: np.ndarray, site: int) -> tuple[int, int]:
        """The grammar's `advance` of `group` (served at `site`, -1: none), then
        round_kernels.prior_pick: SiteOrder's next site and its waiting particles' count."""
        from ngpm_runtime import round_kernels

        rows = self.rows
        site, m = round_kernels.prior_pick(
            group,
            self._advance(group),
            site,
            self.need,
            self.n_prims,
            self.wait_ids,
            self.wait_n,
            self.drawn,
            self.empty,
            self.counts,
            rows.status,
            rows.limit,
            self.reach,
        )
        return int(site), int(m)

    def _outcomes(self) -> tuple[list[int], list[int]]:
        """The step's particles that drew (ascending) and that ended without drawing."""
        counts = self.counts
        return np.sort(self.drawn[: counts[0]]).tolist(), self.empty[: counts[1]].tolist()

    def _derive(self) -> tuple[list[int], list[int]]:
        """run._Run._derive over the arrays: the same rounds in the same order, the step's
        rounds in one call (round_kernels.prior_derive, guided_derive), or round by round
        for feature traces (_derive_rows)."""
        from ngpm_runtime import round_kernels as kernels

        if self.trace is TraceRecording.FULL:
            return self._derive_rows()
        if not self.is_prior:
            return self._derive_guided()
        rows = self.rows
        counts = self.counts
        self.stack, self.tstack, self.vals, self.rec = self._kernel(
            kernels.prior_derive,
            *self._step_state(),
            self.site_kind,
            self.prior_normals,
            rows.log_prior,
            self.rec,
        )
        n_rec = int(counts[2])
        if n_rec:
            rec = self.rec[:n_rec]
            self.trace_pool.add(rec[:, 0].astype(np.int64), rec[:, 1:])
        return self._outcomes()

    def _derive_rows(self) -> tuple[list[int], list[int]]:
        """_derive for a run with feature traces (a proposal that is no RoundProposal: the
        prior, a replay): per round the grammar's `advance`, round_kernels.prior_pick (the
        outcomes, SiteOrder's site), the site's particles packed (pack_waiting) and served
        as run._Run._serve serves one site with features (run._Run._unpack, _propose_one),
        their feature rows into the traces."""
        from ngpm_runtime import round_kernels as kernels

        group = self._start()
        site = -1
        replay = self.replay
        while True:
            site, m = self._pick(group, site)
            if self.rep[1]:
                self._replayed()
            if site < 0:
                break
            flat, group = kernels.pack_waiting(
                np.array([site], dtype=np.int64),
                self.wait_ids,
                self.wait_n,
                self.stack,
                self.sp,
                self.turtle,
                self.t_width,
                self.need,
            )
            obj = self.program.sites[site]
            served, idx = self._unpack(flat, [obj], [group.tolist()], int(self.need[group[0], 1]))
            x = served.features
            assert x is not None  # feature traces: the run has a feature maker
            if not self.use_features:  # features for the trace only
                served = RoundRows(
                    served.sites, served.counts, served.site, served.args, served.n_args, None, []
                )
            if replay is not None:  # a request the kernel left (a mismatch: propose says)
                replay.pos = int(self.rep[0])
            values = np.asarray(self._propose_one(obj, served, idx), dtype=np.float64)
            if replay is not None:
                self.rep[0] = self.replay_at = replay.pos
            self.vals = kernels.take_values(group, values, self.vals, self.nv, self.need)
            feats = x[:, : self.n_feat[site]]
            at = len(self.features)
            self.features.extend(feats[j].copy() for j in range(len(group)))
            self.trace_pool.add(
                group, np.full(len(group), float(site)), values, np.arange(at, at + len(group))
            )
        if replay is not None:
            replay.pos = int(self.rep[0])
        return self._outcomes()

    def _replayed(self) -> None:
        """The site visits the kernel served from a replay's values since the last call
        (logged in pack_waiting's layout, in order; the canvas has not changed since):
        their feature rows in one call, their weights and log prior
        (round_kernels.replay_weights), the visits into the trace, as _derive_rows
        records them."""
        from ngpm_runtime import round_kernels

        rep = self.rep
        at, m = self.replay_at, int(rep[0]) - self.replay_at
        self.replay_at = int(rep[0])
        if self.replay_buf is None or self.replay_buf.n < m:
            self.replay_buf = _Buffers(self.program, max(m, 16), self.t_width)
        buf = self.replay_buf
        buf.unpack(self.log[: rep[1]], int(rep[3]))
        rep[1] = 0
        fmaker = self.fmaker
        assert fmaker is not None
        x = fmaker.rows_from(
            self.canvas, buf.idx[:m], buf.turtle[:m], buf.depth[:m], buf.extra[:m], buf.n_extra[:m]
        )
        values = self.rval[at : at + m]
        site = buf.site[:m]
        rows = self.rows
        round_kernels.replay_weights(
            self.site_kind, site, buf.args[:m], buf.n_args[:m], values, rows.log_w, rows.log_prior
        )
        start = len(self.features)
        n_feat = self.n_feat
        self.features.extend(x[j, : n_feat[s]].copy() for j, s in enumerate(site.tolist()))
        at_feat = np.arange(start, start + m)
        self.trace_pool.add(np.zeros(m, dtype=np.int64), site.astype(np.float64), values, at_feat)

    def _derive_guided(self) -> tuple[list[int], list[int]]:
        """_derive for a guide whose kernel serves every site (Guide.round_tables): per
        round the grammar's `advance`, round_kernels.guided_round (the outcomes, site order, the
        waiting particles packed as run._Run._pack packs them), the run's draws (as
        run._Run._serve_kernel draws them) and round_kernels.serve_take (serve_round, the
        values into the particles)."""
        from ngpm_runtime import round_kernels as kernels

        rows = self.rows
        buf, fmaker = self.buffers, self.fmaker
        assert buf is not None and fmaker is not None
        width_bad, normals, widest, tables = self.guided_tables
        guide: Any = self.proposal
        state = (*buf.state(widest), buf.rows(fmaker.n_common))
        nets = (*fmaker.window_args(self.canvas), *tables, buf.params(guide.widest))
        status, a, b, self.stack, self.tstack, self.vals, self.rec, row_site = self._kernel(
            kernels.guided_derive,
            *self._step_state(),
            width_bad,
            normals,
            *state,
            *nets,
            buf.out,
            rows.log_w,
            rows.log_prior,
            self.rec,
        )
        if status == 1:
            self._round_error(row_site, a, -1, 0)
        elif status == 2:
            self._round_error(row_site, -1, a, b)
        n_rec = int(self.counts[2])
        if n_rec:
            rec = self.rec[:n_rec]
            self.trace_pool.add(rec[:, 0].astype(np.int64), rec[:, 1:])
        return self._outcomes()

    def _guided_tables(self) -> tuple[Any, ...]:
        """What a guided round takes of the guide, once per run: per site whether
        the guide refuses its feature width and whether it draws a normal, the most prior
        arguments of a site, and the nets' tables (Guide.round_tables)."""
        from ngpm_runtime.errors import GuideError

        guide: Any = self.proposal
        sites = self.program.sites
        width_bad = np.zeros(max(len(sites), 1), dtype=np.bool_)
        normals = np.zeros(max(len(sites), 1), dtype=np.bool_)
        for s in sites:
            try:
                guide.check_width(s, 1, self.n_feat[s.index] - self.trim)
            except GuideError:
                width_bad[s.index] = True
            normals[s.index] = guide.needs_normals([s])
        widest = max([s.n_args() for s in sites] or [1])
        return width_bad, normals, widest, self.round_tables(sites)

    def _round_error(self, row_site: np.ndarray, refused: int, bad: int, n: int) -> None:
        """The guide's error for a guided round that stopped: a site whose
        feature width it refuses (check_width), or a row whose prior arguments are bad."""
        guide: Any = self.proposal
        sites, counts = np.unique(row_site, return_counts=True)
        if refused >= 0:
            m = dict(zip(sites.tolist(), counts.tolist(), strict=True)).get(refused, 0)
            guide.check_width(self.program.sites[refused], m, self.n_feat[refused] - self.trim)
        objs = [self.program.sites[s] for s in sites.tolist()]
        buf = self.buffers
        assert buf is not None
        guide.bad_row(objs, counts.tolist(), buf.args[:n], buf.n_args[:n], bad)

    # ---- the rest of a step ---------------------------------------------------------------

    def _fused_observe(self) -> tuple[Any, ...] | None:
        """What round_kernels.observe_step needs of the likelihood, once per run: (its
        code, the target's gain, the viewport, the blank image's value, whether there is
        one); None when it is not the shape or circuit likelihood on a canvas of the
        target's size (_Run._observe then, which reports a wrong size)."""
        from ngpm_runtime import round_kernels as kernels

        like, canvas = self.likelihood, self.canvas
        if canvas is None:
            return None
        if type(like) is ShapeLikelihood and like.target.shape == canvas.image.shape[1:]:
            code, gain = kernels.SHAPE, like.gain_flat
        elif type(like) is CircuitLikelihood:
            code, gain = kernels.CIRCUIT, _NO_GAIN
        else:
            return None
        blank = self.blank_ll
        vp = np.array(like.viewport, dtype=np.float64)
        return code, gain, vp, 0.0 if blank is None else float(blank), blank is not None

    def _observe(self, drawn: list[int], empty: list[int]) -> None:
        """_Run._observe on the arrays: the step's primitives, the particles that ended or
        hit the primitive cap; for the shape and circuit likelihoods in one kernel call
        (round_kernels.observe_step), which also finds the largest weight and the live
        particles (_top, _update_live)."""
        from ngpm_runtime import round_kernels as kernels

        if self.fused is not None:
            self._observe_fused(drawn, empty)
            return
        pool = self.prim_pool
        idx = np.asarray(drawn, dtype=np.int64)
        codes, par, pool.prev, pool.cols = kernels.step_prims(idx, *self._pool_args())
        pool.top += len(idx)
        self.step_prims = PrimRows(codes, par)
        self._observe_prims(drawn, empty, self.step_prims, (codes, par))

    def _pool_args(self) -> _PoolArgs:
        """What round_kernels.step_prims and observe_step take after the step's particles:
        their primitives, stacks, counts and caps, statuses, and the primitive pool's rows."""
        rows, pool = self.rows, self.prim_pool
        return (
            self.prim, self.prim_par, self.sp, self.n_prims, self.cap, rows.status, rows.limit,
            pool.head, pool.prev, pool.cols, pool.top,
        )  # fmt: skip

    def _observe_fused(self, drawn: list[int], empty: list[int]) -> None:
        """_observe in one call of round_kernels.observe_step."""
        from ngpm_runtime import round_kernels as kernels

        assert self.fused is not None and self.canvas is not None
        like, gain, vp, blank, has_blank = self.fused
        state, canvas, pool, rows = self.like_state, self.canvas, self.prim_pool, self.rows
        idx = np.asarray(drawn, dtype=np.int64)
        none = _NO_GAIN
        top, n_live, codes, par, pool.prev, pool.cols = kernels.observe_step(
            idx,
            np.asarray(empty, dtype=np.int64),
            *self._pool_args(),
            canvas.image,
            canvas.padded,
            *canvas.layout(),
            like,
            state.get("sim", none),
            state["bbox"],
            state["ll"],
            state.get("pot", none),
            state.get("edge_sum", none),
            state.get("filled", none),
            gain,
            vp,
            rows.log_w,
            rows.log_lik,
            blank,
            has_blank,
            self.live_ids,
        )
        pool.top += len(idx)
        self.step_prims = PrimRows(codes, par)
        self.top_w = top
        rows.live = self.live_ids[:n_live].tolist()

    def _top(self) -> float:
        return super()._top() if self.fused is None else float(self.top_w)

    def _update_live(self) -> None:
        if self.fused is None:  # else observe_step did
            super()._update_live()

    def _step_done(self, drawn: list[int]) -> None:
        """_Run._step_done with the step's primitives from the arrays."""
        state = self.state
        state.steps = self.steps
        state.log_likelihood = self.rows.log_lik
        state.drawn = drawn
        state.prims = list(self.step_prims)
        for obs in self.observers:
            obs.step_done(state)

    def _take(self) -> np.ndarray:
        """_Run._take in one kernel call (round_kernels.resample_rows: the ancestors, the
        population's rows, the canvases and the deriver's state) of the scheme's draws
        (resample.ancestor_counts: `resample`'s numbers). The rows go into spare arrays of
        the same shapes, which are then swapped in: fresh ones of this size would cost page
        faults every step."""
        from ngpm_runtime import round_kernels

        rows, n = self.rows, self.n
        counts, cum, u = ancestor_counts(self.resample, rows.log_w, self.rng)
        old = (
            self.stack, self.sp, self.turtle, self.tstack, self.tsp, self.vals, self.nv,
            self.need, self.n_prims, self.work,
        )  # fmt: skip  # round_kernels.take_particles' order
        new = self.spare
        if new is None or any([new[k].shape != old[k].shape for k in _GROWING]):
            new = tuple(np.empty_like(a) for a in old)
        pop_old = (rows.status, rows.limit, rows.log_prior, rows.log_lik)
        pop_new = (
            np.empty_like(rows.status),
            np.empty_like(rows.limit),
            np.empty_like(rows.log_prior),
            np.empty_like(rows.log_lik),
        )
        canvas = self.canvas
        image = _NO_IMAGE if canvas is None else canvas.take_args()
        live = np.empty(n, dtype=np.int64)
        anc, n_live = round_kernels.resample_rows(
            counts, cum, u, live, *pop_old, *pop_new, *image, *old, *new
        )
        rows.took(pop_new, live[:n_live].tolist())
        (
            self.stack, self.sp, self.turtle, self.tstack, self.tsp, self.vals, self.nv,
            self.need, self.n_prims, self.work,
        ) = new  # fmt: skip
        self.spare = old
        if canvas is not None:
            canvas.swap()
        self.prim_pool.take(anc)
        self.trace_pool.take(anc)
        take_arrays(self.like_state, anc)
        return anc

    def _limit_live(self, reason: str) -> None:
        self.rows.stop_live(LIMITS.index(reason))

    def result(self, seconds: float) -> SMCResult:
        pop = self.rows
        prims = self.prim_pool.lists(_made_prims)
        traces: list[Any] = [None] * self.n
        if self.trace is TraceRecording.VALUES:
            traces = self.trace_pool.lists(_made_trace)
        elif self.trace is TraceRecording.FULL:
            features = self.features
            traces = self.trace_pool.lists(
                lambda rows, cols: [(int(c[0]), features[int(c[2])], c[1]) for c in cols.tolist()]
            )
        finals = [
            FinalParticle(
                primitives=prims[i],
                log_prior=lp,
                log_likelihood=ll,
                log_weight=lw,
                trace=traces[i],
                status=STATUS[st],
                limit=LIMITS[lim] if st == LIMITED else None,
            )
            for i, (lp, ll, lw, st, lim) in enumerate(
                zip(
                    pop.log_prior.tolist(),
                    pop.log_lik.tolist(),
                    pop.log_w.tolist(),
                    pop.status.tolist(),
                    pop.limit.tolist(),
                    strict=True,
                )
            )
        ]
        return self._result(finals, seconds, {"deriver": "compiled"})


class PrimRows(Sequence[Prim]):
    """Primitives held as the draw kernel's arrays (kind codes, parameters), made into
    tuples when read (DrawBatch.prims for a likelihood that reads them)."""

    def __init__(self, codes: np.ndarray, par: np.ndarray) -> None:
        self.codes = codes
        self.par = par

    def __len__(self) -> int:
        return len(self.codes)

    @overload
    def __getitem__(self, k: int) -> Prim: ...

    @overload
    def __getitem__(self, k: slice) -> list[Prim]: ...

    def __getitem__(self, k: int | slice) -> Prim | list[Prim]:
        if isinstance(k, slice):
            return [self[j] for j in range(*k.indices(len(self)))]
        return _prim(int(self.codes[k]), self.par[k].tolist())


def _prim(code: int, row: list[float]) -> Prim:
    return (_PRIM_KINDS[code], *row[: 3 if code == 1 else 5])


class _Pool:
    """Per-particle lists that share their past, as cons lists do (the primitives drawn,
    the values drawn): rows (value columns, previous row) in arrays; `head[i]` is particle
    i's newest row (-1: none); resampling copies heads only."""

    def __init__(self, n: int, width: int) -> None:
        self.head = np.full(n, -1, dtype=np.int64)
        self.prev = np.zeros(1024, dtype=np.int64)
        self.cols = np.zeros((1024, width))
        self.top = 0

    def add(self, idx: np.ndarray, *columns: np.ndarray) -> None:
        """Rows made of `columns` (one row per entry of idx) become the newest of lists
        idx, in turn (an index may repeat)."""
        m = len(idx)
        if not m:
            return
        from ngpm_runtime import round_kernels as kernels

        if self.top + m > len(self.prev):
            size = max(2 * len(self.prev), self.top + m)
            self.prev = np.resize(self.prev, size)
            self.cols = np.resize(self.cols, (size, self.cols.shape[1]))
        c = 0
        for col in columns:
            block = col.reshape(m, -1)
            self.cols[self.top : self.top + m, c : c + block.shape[1]] = block
            c += block.shape[1]
        kernels.link_rows(self.head, self.prev, self.top, np.asarray(idx, dtype=np.int64))
        self.top += m

    def take(self, anc: np.ndarray) -> None:
        self.head = self.head[anc]

    def lists(self, made: Callable[[np.ndarray, np.ndarray], list[Any]]) -> list[list[Any]]:
        """Every particle's list, oldest first: its rows as `made(rows, columns)` makes
        them (one item per row; a row shared by several lists is made once)."""
        from ngpm_runtime import round_kernels as kernels

        ids, starts = kernels.chain_rows(self.head, self.prev)
        used = np.zeros(self.top, dtype=np.bool_)
        used[ids] = True
        rows = np.flatnonzero(used)
        table = np.empty(self.top, dtype=object)
        table[rows] = _objects(made(rows, self.cols[rows]))
        flat = table[ids].tolist()
        at = starts.tolist()
        return [flat[at[i] : at[i + 1]] for i in range(len(at) - 1)]


def _objects(items: list[Any]) -> np.ndarray:
    """A 1-d object array of `items` (tuples stay items, not rows)."""
    return np.fromiter(items, dtype=object, count=len(items))


def _made_prims(rows: np.ndarray, cols: np.ndarray) -> list[Prim]:
    """Primitive tuples of prim pool rows (kind code, parameters)."""
    out: list[Any] = [None] * len(rows)
    codes = cols[:, 0]
    for code, kind in enumerate(_PRIM_KINDS):
        at = np.flatnonzero(codes == code)
        if len(at):
            width = 3 if kind == "disk" else 5
            made = zip(repeat(kind), *(cols[at, 1 + j].tolist() for j in range(width)))
            for k, prim in zip(at.tolist(), made, strict=True):
                out[k] = prim
    return out


def _made_trace(rows: np.ndarray, cols: np.ndarray) -> list[Any]:
    """(site, None, value) of trace pool rows (site, value)."""
    sites = cols[:, 0].astype(np.int64).tolist()
    return list(zip(sites, repeat(None), cols[:, 1].tolist()))
