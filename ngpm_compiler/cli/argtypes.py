"""argparse value types shared by the `ngpmc` commands: bad values are refused while the
command line is parsed, with one line that names the option's rule."""

from __future__ import annotations

import argparse
from typing import Any

MAX_RENDER_SIZE = 8192  # pixels per side of a rendered image (`sample --size`)


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None


def seed(text: str) -> int:
    """A random seed: an integer from 0 to 2**63 - 1 (numpy refuses negative seeds)."""
    value = _integer(text)
    if not 0 <= value < 2**63:
        raise argparse.ArgumentTypeError(
            f"seeds are integers from 0 to 2**63 - 1, got {value}")
    return value


def positive(text: str) -> int:
    """An integer of at least 1."""
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def render_size(text: str) -> int:
    """An image size in pixels, 1 to MAX_RENDER_SIZE."""
    value = _integer(text)
    if not 1 <= value <= MAX_RENDER_SIZE:
        raise argparse.ArgumentTypeError(
            f"image sizes are 1 to {MAX_RENDER_SIZE} pixels, got {value}")
    return value


def add_max_modules(parser: argparse.ArgumentParser) -> None:
    """The `--max-modules N` run option (the grammar's `max modules:` cap, overridden)."""
    parser.add_argument(
        "--max-modules", type=positive, default=None, metavar="N",
        help="modules one particle may expand or interpret between two drawings before "
             "it stops with status limit (default: the grammar's 'max modules:', else "
             "20000)")


def limit_note(particle: Any, program: Any, max_modules: int | None) -> str | None:
    """One line saying which cap stopped `particle`, and how to raise it; None if none did."""
    if getattr(particle, "status", None) != "limit" or not getattr(particle, "limit", None):
        return None
    from ngpm_runtime.inference.smc import module_cap

    if particle.limit == "max modules":
        return (f"status limit: max modules ({module_cap(program, max_modules)} modules "
                "expanded in one step without drawing); raise it with --max-modules or a "
                "'max modules:' line, or make the grammar draw sooner")
    if particle.limit == "max primitives":
        return (f"status limit: max primitives ({program.max_primitives} drawn); raise it "
                "with a 'max primitives:' line")
    return f"status limit: {particle.limit}"
