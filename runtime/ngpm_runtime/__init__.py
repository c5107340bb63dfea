"""ngpm_runtime: the torch-free runtime for neurally-guided procedural models.

`grow(program, target, guide)` grows a vine into a target; `bundled` holds the vines
model, its pretrained guide and demo targets. Packages: `geometry` (derivation, turtle),
`image` (raster, features, render, targets), `inference` (SMC, proposals, guide,
likelihoods).
"""

from ngpm_runtime.errors import GuideError, NgpmError, ProgramError, SMCFailed, TargetError
from ngpm_runtime.grow import GrowResult, grow
from ngpm_runtime.image.targets import Target, load_target
from ngpm_runtime.inference.guide import Guide
from ngpm_runtime.inference.likelihood import CircuitLikelihood, NullLikelihood, ShapeLikelihood
from ngpm_runtime.inference.proposals import FixedProposal, PriorProposal
from ngpm_runtime.inference.smc import FinalParticle, SMCOptionError, SMCResult, forward, smc
from ngpm_runtime.program import Program, Site, load_program

__all__ = [
    "NgpmError",
    "SMCFailed",
    "TargetError",
    "GuideError",
    "ProgramError",
    "SMCOptionError",
    "Program",
    "Site",
    "load_program",
    "grow",
    "GrowResult",
    "Target",
    "load_target",
    "Guide",
    "ShapeLikelihood",
    "CircuitLikelihood",
    "NullLikelihood",
    "forward",
    "smc",
    "SMCResult",
    "FinalParticle",
    "PriorProposal",
    "FixedProposal",
]
