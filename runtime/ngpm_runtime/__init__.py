"""ngpm_runtime: the torch-free runtime for neurally-guided procedural models."""

from ngpm_runtime.errors import GuideError, NgpmError, ProgramError, SMCFailed, TargetError
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
    "forward",
    "smc",
    "SMCResult",
    "FinalParticle",
    "PriorProposal",
    "FixedProposal",
]
