"""ngpm_runtime: the torch-free runtime for neurally-guided procedural models."""

from ngpm_runtime.errors import GuideError, NgpmError, ProgramError, SMCFailed, TargetError

__all__ = ["NgpmError", "SMCFailed", "TargetError", "GuideError", "ProgramError"]
