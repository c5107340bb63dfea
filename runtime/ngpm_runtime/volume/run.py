"""What smc() and grow() build for a 3D grammar (Program.dim == 3): the voxel canvas, the
voxel likelihood and the 3D feature maker, all on one voxel grid."""

from __future__ import annotations

from typing import Any

from ngpm_runtime.errors import ProgramError, printable
from ngpm_runtime.inference.likelihood import SHAPE_SIGMA
from ngpm_runtime.program import Program
from ngpm_runtime.volume.features import DEFAULT_WINDOW, FeatureMaker3D
from ngpm_runtime.volume.likelihood import VoxelLikelihood, check_box
from ngpm_runtime.volume.raster import VoxelCanvas, VoxelGrid


def volume_likelihood(program: Program, target: Any, sigma: float | None = None) -> VoxelLikelihood:
    """Equation 1 on voxels against a VolumeTarget, bounds against the program's box
    (sigma: the equation's, default SHAPE_SIGMA)."""
    box = check_box(program.box, printable(program.name))
    return VoxelLikelihood(target, box, SHAPE_SIGMA if sigma is None else sigma)


def run_grid(program: Program, likelihood: Any, volume: Any) -> VoxelGrid:
    """The grid of a 3D run: the target's (the likelihood's or the `volume` option's, which
    must agree), else a cube over the program's box."""
    grids = [VoxelGrid.of_target(t) for t in (volume,) if t is not None]
    if isinstance(likelihood, VoxelLikelihood):
        grids.append(likelihood.grid)
    if grids:
        if any(g != grids[0] for g in grids):
            raise ProgramError("the 3D target of the features and of the likelihood differ")
        return grids[0]
    return VoxelGrid.of_box(check_box(program.box, printable(program.name)))


def canvas_and_features(
    program: Program,
    likelihood: Any,
    n: int,
    volume: Any,
    need_features: bool,
    target_mask: Any = None,
    window: str | None = None,
) -> tuple[VoxelCanvas | None, FeatureMaker3D | None]:
    """smc()'s canvas and feature maker for a 3D grammar. The likelihood: None, one that
    needs no canvas (it gets PrimBatches), or a VoxelLikelihood; `volume` (a VolumeTarget,
    optional) is what the features' target windows read (default: the likelihood's);
    `window` the features' window (volume/features.py; None: the default)."""
    name = printable(program.name)
    if target_mask is not None:
        raise ProgramError(
            f"{name} is a 3D grammar: give a 3D target (SMCOptions.volume), not a target mask"
        )
    if likelihood is not None and likelihood.needs_canvas:
        if not isinstance(likelihood, VoxelLikelihood):
            raise ProgramError(
                f"{name} is a 3D grammar and {type(likelihood).__name__} is a 2D likelihood: "
                "grow a 3D grammar into a 3D target (VoxelLikelihood)"
            )
    if not (need_features or (likelihood is not None and likelihood.needs_canvas)):
        return None, None
    grid = run_grid(program, likelihood, volume)
    canvas = VoxelCanvas(n, grid, pyramid=need_features)
    if not need_features:
        return canvas, None
    if volume is None and isinstance(likelihood, VoxelLikelihood):
        volume = likelihood.source
    return canvas, FeatureMaker3D(program, grid, volume, window=window or DEFAULT_WINDOW)


def start_pose(program: Program, target: Any) -> tuple[float, float, float, float]:
    """(x, y, z, heading): the target's start point, the program's start heading."""
    x, y, z = (float(v) for v in target.start)
    return x, y, z, float(program.start[2])
