"""ngpm_runtime: the torch-free runtime for neurally-guided procedural models.

`grow(program, target, guide)` grows a vine into a target; `bundled` holds the vines
model, its pretrained guide and demo targets. Packages: `geometry` (derivation, turtle,
meshes and mesh files), `image` (raster, features, render, targets, pictures of meshes),
`inference` (SMC, proposals, guide, likelihoods).

`grow` is imported here (the module `ngpm_runtime.grow` has the function's name, so the
package binds the function after importing it); the other names below are imported on
first use, so the guide's onnxruntime loads only when a guide is used.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

from ngpm_runtime.grow import GrowResult as GrowResult
from ngpm_runtime.grow import grow as grow

_EXPORTS = {
    "NgpmError": "ngpm_runtime.errors",
    "SMCFailed": "ngpm_runtime.errors",
    "TargetError": "ngpm_runtime.errors",
    "GuideError": "ngpm_runtime.errors",
    "ProgramError": "ngpm_runtime.errors",
    "Program": "ngpm_runtime.program",
    "Site": "ngpm_runtime.program",
    "load_program": "ngpm_runtime.program",
    "Mesh": "ngpm_runtime.geometry.mesh",
    "MeshError": "ngpm_runtime.geometry.mesh",
    "mesh_from_primitives": "ngpm_runtime.geometry.mesh",
    "render_mesh": "ngpm_runtime.image.render3d",
    "Target": "ngpm_runtime.image.targets",
    "load_target": "ngpm_runtime.image.targets",
    "Guide": "ngpm_runtime.inference.guide",
    "ShapeLikelihood": "ngpm_runtime.inference.likelihood",
    "CircuitLikelihood": "ngpm_runtime.inference.likelihood",
    "NullLikelihood": "ngpm_runtime.inference.likelihood",
    "PriorProposal": "ngpm_runtime.inference.proposals",
    "FixedProposal": "ngpm_runtime.inference.proposals",
    "forward": "ngpm_runtime.inference.smc",
    "smc": "ngpm_runtime.inference.smc",
    "SMCResult": "ngpm_runtime.inference.smc",
    "FinalParticle": "ngpm_runtime.inference.smc",
    "SMCOptionError": "ngpm_runtime.inference.smc",
    "SMCOptions": "ngpm_runtime.inference.smc",
    "SMCObserver": "ngpm_runtime.inference.smc",
    "SMCState": "ngpm_runtime.inference.smc",
    "TraceRecording": "ngpm_runtime.inference.smc",
}

__all__ = sorted([*_EXPORTS, "grow", "GrowResult"])


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'ngpm_runtime' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
