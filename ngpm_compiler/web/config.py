"""What `ngpmc serve` offers and accepts: the grammars and guides on offer (`load_config`) and
the server's limits (`Limits`, which the page reads from /api/options)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ngpm_runtime.errors import GuideError, NgpmError
from ngpm_runtime.program import Program

if TYPE_CHECKING:
    from ngpm_runtime.inference.guide import Guide

log = logging.getLogger("ngpmc.serve")


@dataclass(frozen=True)
class Limits:
    """What the server accepts; the page reads them from /api/options."""

    max_body_bytes: int = 12 * 2**20  # a JSON request (the image travels as base64)
    max_image_bytes: int = 8 * 2**20  # the decoded image file
    max_side: int = 4096  # pixels, each side of the image
    max_particles: int = 500
    default_particles: int = 10
    timeout_s: float = 60.0  # per run
    max_runs: int = 2  # runs at once, over all clients; also pictures decoded at once
    target_size: int = 50  # the model's target resolution (as `ngpmc grow --size`)
    request_timeout_s: float = 10.0  # a request's line, headers and body must arrive in it
    max_connections: int = 32  # uvicorn's limit_concurrency: beyond it requests get 503


@dataclass
class GuideChoice:
    id: str
    name: str
    guide: Guide


@dataclass
class GrammarChoice:
    id: str
    name: str
    source: str  # "bundled" or "command line"
    program: Program
    guides: list[GuideChoice] = field(default_factory=list)


@dataclass
class WebConfig:
    grammars: list[GrammarChoice]
    limits: Limits = field(default_factory=Limits)

    def grammar(self, gid: str) -> GrammarChoice | None:
        return next((g for g in self.grammars if g.id == gid), None)


def _load_grammar(path: str) -> Program:
    from ngpm_compiler.language.compile import load_grammar

    if not Path(path).is_file():
        raise NgpmError(f"{path}: no such grammar file")
    return load_grammar(path)


def load_config(
    grammar: str | None = None, guide: str | None = None, limits: Limits | None = None
) -> WebConfig:
    """The bundled vines model and guide, plus the grammar and guide of the command line
    (`--guide` alone is a guide for the bundled vines; `--guide none`: offer no guide)."""
    from ngpm_runtime import bundled
    from ngpm_runtime.inference.guide import Guide

    vines = GrammarChoice("vines", "vines", "bundled", bundled.bundled_program())
    try:
        vines.guides.append(
            GuideChoice("bundled", "bundled vines guide", bundled.bundled_guide(vines.program))
        )
    except GuideError as err:  # a checkout without the guide file: unguided only
        log.warning("%s", err)
    choices = [vines]
    no_guide = guide is not None and guide.lower() == "none"
    if grammar is None:
        if guide is not None and not no_guide:
            vines.guides.insert(
                0, GuideChoice("cli", Path(guide).name, Guide.load(guide, vines.program))
            )
        elif no_guide:
            vines.guides.clear()
        return WebConfig(choices, limits or Limits())
    program = _load_grammar(grammar)
    if program.dim != 2:
        raise NgpmError(
            f"{grammar} is a 3D grammar: the page grows 2D grammars into pictures; "
            f"see a 3D grammar with `ngpmc sample {grammar} -o tree.glb --png "
            "tree.png`"
        )
    mine = GrammarChoice(
        "cli",
        f"{program.name or Path(grammar).stem} ({Path(grammar).name})",
        "command line",
        program,
    )
    if program.viewport is None:
        raise NgpmError(f"grammar {grammar} has no viewport: cannot grow into a picture")
    if guide is not None and not no_guide:
        mine.guides.append(GuideChoice("cli", Path(guide).name, Guide.load(guide, program)))
    elif not no_guide and program.grammar_hash == vines.program.grammar_hash:
        mine.guides = list(vines.guides)
    return WebConfig([mine, *choices], limits or Limits())
