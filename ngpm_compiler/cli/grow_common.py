"""What `ngpmc grow` shares in 2D (grow.py) and 3D (grow3d.py): the similarity scale it
explains, the default guide and the progress ticks."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ngpm_runtime.program import Program

if TYPE_CHECKING:
    from ngpm_runtime.inference.guide import Guide
    from ngpm_runtime.inference.smc import SMCObserver

    from ngpm_compiler.progress import Progress

SIMILARITY_SCALE = (
    "1 = the target exactly, 0 = no better than a blank canvas, below 0 = "
    "worse than blank (more drawn outside the shape than inside)"
)
LOW_SIMILARITY = 0.2  # below it, grow explains the scale


def _grow_guide(choice: str | None, program: Program, likelihood: str) -> Guide | None:
    """The guide to use: a file, 'none', or by default the bundled guide for this grammar
    and likelihood (none bundled: unguided, saying so)."""
    from ngpm_runtime import bundled
    from ngpm_runtime.inference.guide import Guide

    if choice is not None and choice.lower() == "none":
        return None
    if choice is not None:
        return Guide.load(choice, program)
    guide = bundled.default_guide(program, likelihood)
    if guide is None:
        print(
            f"no bundled guide for grammar {program.name} with the {likelihood} "
            "likelihood: unguided SMC (train one with ngpmc traces, train and export; "
            "pass it with --guide)"
        )
    return guide


def _step_ticks(bar: Progress) -> SMCObserver:
    """An SMC observer that ticks `bar` once per step that drew (imported late: the CLI
    starts without the SMC modules)."""
    from ngpm_runtime.inference.smc import SMCObserver, SMCState

    class StepTicks(SMCObserver):
        def step_done(self, state: SMCState) -> None:
            if state.drawn:
                bar.update(1)

    return StepTicks()
