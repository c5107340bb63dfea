"""grow(): a target in, a vine out. The one place that runs SMC into a target.

The CLI (`ngpmc grow`), trace recording and the evaluation all call `grow`, so a run with
the same program, target, guide, particle count and seed gives the same vine everywhere.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from ngpm_runtime.errors import NgpmError, printable
from ngpm_runtime.geometry.turtle import Prim
from ngpm_runtime.image.raster import Viewport, rasterize
from ngpm_runtime.inference.likelihood import (
    CircuitLikelihood,
    Likelihood,
    ShapeLikelihood,
    circuit_score,
    similarity,
)
from ngpm_runtime.inference.proposals import Proposal
from ngpm_runtime.inference.smc import (
    SMCObserver,
    SMCOptions,
    SMCResult,
    TraceRecording,
    smc,
)
from ngpm_runtime.program import Program, require_2d

if TYPE_CHECKING:  # targets loads PIL: only when a target is made
    from ngpm_runtime.image.targets import Target
    from ngpm_runtime.volume.target import VolumeTarget

LIKELIHOODS = ("shape", "circuit")
DEFAULT_CANVAS = (50, 50)  # raster size when there is no target
# where a circuit run starts without a picture: bottom middle, heading up (normalized
# image coordinates x y, then the direction dx dy in image axes, as a start sidecar)
CIRCUIT_START = (0.5, 0.95, 0.0, -1.0)


@dataclass
class GrowResult:
    """The best particle of one SMC run into a target."""

    # the best particle's score: its raster's similarity to the target (shape), or
    # equation 2's argument (circuit, `circuit_score`); nan for a shape run without a target
    similarity: float
    seconds: float  # time in SMC (not counting the final raster)
    particles: int
    primitives: list[Prim]
    image: np.ndarray  # (H, W) uint8 raster of the best particle; 3D: its (R, R, R) voxels
    smc: SMCResult


def _viewport(program: Program) -> Viewport:
    require_2d(program, "growing into a picture")
    if program.viewport is None:
        name = printable(program.source or program.name)
        raise NgpmError(
            f"grammar {name} has no viewport: cannot grow into a target; add a "
            "'viewport: XMIN XMAX YMIN YMAX' line (`ngpmc check GRAMMAR` "
            "proposes one from forward samples)"
        )
    return program.viewport


def make_likelihood(kind: str, program: Program, target: Target | None = None) -> Likelihood:
    """The likelihood named `kind` ("shape": match the target's mask; "circuit")."""
    viewport = _viewport(program)
    if kind == "shape":
        if target is None:
            raise NgpmError("the shape likelihood needs a target image")
        return ShapeLikelihood(target.mask, viewport)
    if kind == "circuit":
        return CircuitLikelihood(viewport)
    raise NgpmError(f"unknown likelihood {kind!r}; choose {' or '.join(LIKELIHOODS)}")


def circuit_target(size: tuple[int, int] = DEFAULT_CANVAS) -> Target:
    """What a circuit run grows into without a picture: a blank canvas of `size` (height,
    width) with the start CIRCUIT_START. Circuit traces, tuning and evaluation use it."""
    from ngpm_runtime.image.targets import Target

    return Target(np.zeros(size, dtype=bool), CIRCUIT_START, "circuit")


def grow(
    program: Program,
    target: Target | VolumeTarget | None = None,
    guide: Proposal | None = None,
    n_particles: int = 10,
    seed: int = 0,
    likelihood: str = "shape",
    *,
    observers: Sequence[SMCObserver] = (),
    trace: TraceRecording = TraceRecording.NONE,
    start: tuple[float, ...] | None = None,
    canvas_size: tuple[int, int] | None = None,
    max_modules: int | None = None,
    sigma: float | None = None,
) -> GrowResult:
    """SMC (guided when `guide` is given) into `target`; the best particle and its score.

    target: a `ngpm_runtime.image.targets.Target` (mask + start pose), or None with the
    circuit likelihood. likelihood: "shape" (match the target) or "circuit" (the target,
    optional, only gives the start pose and the canvas size, default `circuit_target()`;
    the guide sees no target, and the score is `circuit_score`). observers: SMC
    observers (a progress bar, live frames, a time limit; one may raise to stop the run).
    trace (what each particle's trace records), start (world pose overriding the target's),
    canvas_size (default: the target's size) and max_modules (the grammar's "max modules"
    cap, overridden) go to `smc`, which resamples as the guide's settings say
    (`Guide.settings.ess_threshold`; unguided SMC resamples every step).
    sigma: the voxel likelihood's sigma (3D only; default 0.02, the paper's): a softer
    one (e.g. 0.05) keeps more particles alive, which makes stronger trace teachers.

    A 3D grammar grows into a `VolumeTarget` (volume/target.py) with the voxel likelihood
    ("shape" only; canvas_size is not used; start may be (x, y, z, heading)).
    """
    if program.dim == 3:
        return _grow3d(
            program,
            target,
            guide,
            n_particles,
            seed,
            likelihood,
            observers,
            trace,
            start,
            max_modules,
            sigma,
        )
    if sigma is not None:
        raise NgpmError("sigma is an option of 3D grammars' voxel likelihood only")
    target = cast("Target | None", target)  # a 2D grammar: a picture's Target
    viewport = _viewport(program)
    like: Likelihood = make_likelihood(likelihood, program, target)
    if likelihood == "circuit" and target is None:
        target = circuit_target(canvas_size or DEFAULT_CANVAS)
    mask = target.mask if target is not None and likelihood == "shape" else None
    if canvas_size is None:
        canvas_size = target.size if target is not None else DEFAULT_CANVAS
    if start is None and target is not None:
        start = target.start_pose(viewport)
    t0 = time.perf_counter()
    options = SMCOptions(
        seed=seed,
        ess_from_proposal=True,
        trace=trace,
        start=start,
        canvas_size=canvas_size,
        target_mask=mask,
        max_modules=max_modules,
    )
    result = smc(program, like, n_particles, guide, options, observers)
    seconds = time.perf_counter() - t0
    prims = list(result.best.primitives)
    image = rasterize(prims, viewport, *canvas_size)
    if likelihood == "circuit":
        sim = circuit_score(image)
    else:
        sim = float(similarity(image, mask)) if mask is not None else float("nan")
    return GrowResult(sim, seconds, n_particles, prims, image, result)


def _grow3d(
    program: Program,
    target: Any,
    guide: Proposal | None,
    n_particles: int,
    seed: int,
    likelihood: str,
    observers: Sequence[SMCObserver],
    trace: TraceRecording,
    start: tuple[float, ...] | None,
    max_modules: int | None,
    sigma: float | None = None,
) -> GrowResult:
    """grow() of a 3D grammar into a VolumeTarget: similarity and image are the best
    particle's voxels on the target's grid."""
    from ngpm_runtime.volume.raster import VoxelGrid, voxelize
    from ngpm_runtime.volume.run import start_pose, volume_likelihood

    if likelihood != "shape":
        raise NgpmError(f"a 3D grammar grows with the shape likelihood only, not {likelihood!r}")
    if target is None or not hasattr(target, "occupancy"):
        raise NgpmError(f"{printable(program.name)} is a 3D grammar: it grows into a 3D target")
    like = volume_likelihood(program, target, sigma)
    t0 = time.perf_counter()
    options = SMCOptions(
        seed=seed,
        ess_from_proposal=True,
        trace=trace,
        start=start_pose(program, target) if start is None else start,
        max_modules=max_modules,
        volume=target,
    )
    result = smc(program, like, n_particles, guide, options, observers)
    seconds = time.perf_counter() - t0
    prims = list(result.best.primitives)
    voxels = voxelize(prims, VoxelGrid.of_target(target))
    sim = like.similarity(voxels)
    return GrowResult(sim, seconds, n_particles, prims, voxels, result)
