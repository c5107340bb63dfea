"""Sequential Monte Carlo over a compiled program: `smc()`, `forward()`, `replay()`
(architecture.md sections 3, 5, 8). A run's state and step are run.py's `_Run`, or
compiled_run.py's `CompiledRun` where the compiled deriver can run it (`_compiled_deriver`);
this module re-exports the types a caller needs (SMCOptions, SMCResult, ...).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ngpm_runtime.inference.likelihood import Likelihood
from ngpm_runtime.inference.proposals import PriorProposal, Proposal, RoundProposal
from ngpm_runtime.inference.resample import SCHEMES
from ngpm_runtime.inference.run import (
    LOG_NEGLIGIBLE_LIVE,
    NEGLIGIBLE_LIVE,
    FinalParticle,
    Population,
    SiteOrder,
    SMCObserver,
    SMCOptionError,
    SMCOptions,
    SMCResult,
    SMCState,
    TraceRecording,
    Tuned,
    _Run,
    check_run_options,
    module_cap,
    proposal_ess,
    start_particles,
    take_arrays,
)
from ngpm_runtime.program import Program

if TYPE_CHECKING:
    from ngpm_runtime.volume.target import VolumeTarget

__all__ = [
    "COMPILE_FROM",
    "LOG_NEGLIGIBLE_LIVE",
    "NEGLIGIBLE_LIVE",
    "USE_COMPILED",
    "FinalParticle",
    "Population",
    "SMCObserver",
    "SMCOptionError",
    "SMCOptions",
    "SMCResult",
    "SMCState",
    "SiteOrder",
    "TraceRecording",
    "Tuned",
    "check_run_options",
    "forward",
    "module_cap",
    "proposal_ess",
    "replay",
    "smc",
    "start_particles",
    "take_arrays",
]

USE_COMPILED = True  # unguided runs on the compiled deriver where it can (compiled_run.py)
# particles from which a run compiles its grammar's deriver (about 6 s the first time, a
# disk cache later); smaller runs use it once compiled (in this process or on disk)
COMPILE_FROM = 100


def forward(
    program: Program,
    seed: int = 0,
    start: tuple[float, float, float] | None = None,
    max_modules: int | None = None,
) -> FinalParticle:
    """One prior sample of the program: SMC with one particle and no likelihood."""
    options = SMCOptions(seed=seed, start=start, max_modules=max_modules)
    return smc(program, None, 1, options=options).particles[0]


def smc(
    program: Program,
    likelihood: Likelihood | None,
    n_particles: int,
    proposal: Proposal | None = None,
    options: SMCOptions = SMCOptions(),
    observers: Sequence[SMCObserver] = (),
) -> SMCResult:
    """Run SMC; `likelihood=None` (or a NullLikelihood) means no likelihood, no canvas.

    A likelihood with `needs_canvas = False` gets, instead of raster's DrawBatch, a
    `PrimBatch` (idx, bbox, prims); with a canvas, the DrawBatch also carries `.prims`.
    `options` (SMCOptions) holds the seed, resampling, trace recording, canvas and caps;
    `observers` watch the run (SMCObserver).
    """
    t0 = time.perf_counter()
    check_run_options(n_particles, options.seed, options.max_modules)
    n = int(n_particles)
    threshold = _check_options(n, proposal, options)
    args = (program, likelihood, n, proposal, options, tuple(observers))
    compiled = _compiled_deriver(*args)
    if compiled is not None:
        from ngpm_runtime.inference.compiled_run import CompiledRun, KernelFailed

        try:
            return _finish(CompiledRun(compiled, *args), threshold, options.max_steps, t0)
        except KernelFailed:  # the Python deriver runs it again and reports the error
            pass
    return _finish(_Run(*args), threshold, options.max_steps, t0)


def _finish(run: _Run, threshold: float | None, max_steps: int | None, t0: float) -> SMCResult:
    """Step `run` until no particle is live (or max_steps); its result."""
    while run.pop.live:
        if max_steps is not None and run.steps >= max_steps:
            run.stop_live("max steps")
            break
        run.step(threshold)
    return run.result(time.perf_counter() - t0)


def _kernel_guide(proposal: Proposal, program: Program) -> bool:
    """Whether `proposal` is a guide whose kernel serves every site of `program` from 2D
    features (Guide.round_tables), as the compiled deriver's rounds need."""
    tables = getattr(proposal, "round_tables", None)
    return (
        isinstance(proposal, RoundProposal)
        and bool(proposal.uses_features)
        and tables is not None
        and tables(program.sites) is not None
    )


def _compiled_deriver(
    program: Program,
    likelihood: Likelihood | None,
    n: int,
    proposal: Proposal | None,
    options: SMCOptions,
    observers: tuple[SMCObserver, ...],
) -> Any:
    """The program's compiled deriver when the run can use it (compiled_run.py): the
    prior proposal or a guide whose kernel serves every site, or feature traces of a
    proposal that is no RoundProposal (a replay); no observer of site draws, a 2D grammar
    the kernel can run, and COMPILE_FROM particles or more unless the deriver is compiled
    already."""
    if not USE_COMPILED:
        return None
    if any(type(o).site_drawn is not SMCObserver.site_drawn for o in observers):
        return None  # it watches every draw: the Python deriver's rounds tell it
    if program.dim != 2:
        return None
    prior = proposal is None or type(proposal) is PriorProposal
    if options.trace is TraceRecording.FULL:
        if isinstance(proposal, RoundProposal):
            return None  # a guide's rounds with feature traces: run._Run's
    elif not (prior or (proposal is not None and _kernel_guide(proposal, program))):
        return None
    from ngpm_runtime.geometry.compiled import compiled_deriver

    return compiled_deriver(program, compile=n >= COMPILE_FROM)


def _check_options(n: int, proposal: Proposal | None, options: SMCOptions) -> float | None:
    """SMCOptionError for an option that cannot be used; returns the ESS threshold."""
    if n < 1:
        raise SMCOptionError(f"need at least one particle, got {n}")
    if options.resample not in SCHEMES:
        raise SMCOptionError(
            f"unknown resampling scheme {options.resample!r} (choose from {', '.join(SCHEMES)})"
        )
    if not isinstance(options.trace, TraceRecording):
        raise SMCOptionError(f"trace must be a TraceRecording, got {options.trace!r}")
    ess = options.ess_threshold
    if options.ess_from_proposal:
        if ess is not None:
            raise SMCOptionError("give ess_threshold or ess_from_proposal, not both")
        ess = proposal_ess(proposal)
    if ess is not None and (
        isinstance(ess, bool) or not isinstance(ess, int | float) or not 0.0 < ess <= 1.0
    ):
        raise SMCOptionError(f"ess_threshold must be in (0, 1] or None, got {ess!r}")
    mask, size = options.target_mask, options.canvas_size
    if mask is not None and tuple(np.shape(mask)) != tuple(size):
        raise SMCOptionError(
            f"target mask {tuple(np.shape(mask))} and canvas size {tuple(size)} differ"
        )
    return ess


def replay(
    program: Program,
    values: list[tuple[int, float]],
    start: tuple[float, ...] | None = None,
    canvas_size: tuple[int, int] = (50, 50),
    target_mask: np.ndarray | None = None,
    max_primitives: int | None = None,
    max_modules: int | None = None,
    volume: VolumeTarget | None = None,
) -> FinalParticle:
    """The one derivation that makes the given (site, value) choices, with its full trace
    (features as a run with `TraceRecording.FULL` computes them); no likelihood. A 3D
    grammar's features read `volume` (its start may be (x, y, z, heading))."""
    from ngpm_runtime.inference.proposals import ReplayProposal

    proposal = ReplayProposal(values)
    options = SMCOptions(
        trace=TraceRecording.FULL,
        start=start,
        canvas_size=canvas_size,
        target_mask=target_mask,
        max_primitives=max_primitives,
        max_modules=max_modules,
        volume=volume,
    )
    res = smc(program, None, 1, proposal, options)
    proposal.check_used()
    return res.particles[0]
