"""argparse value types shared by the `ngpmc` commands: bad values are refused while the
command line is parsed, with one line that names the option's rule (argparse adds the
option's name and exits with code 2)."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ngpm_runtime.image.resolution import MIN_SIDE  # not targets: no PIL at start-up

if TYPE_CHECKING:  # the SMC loads only for the commands that run it
    from ngpm_runtime.inference.smc import FinalParticle
    from ngpm_runtime.program import Program

MAX_RENDER_SIZE = 8192  # pixels per side of a rendered image (`sample --size`)
MAX_TARGET_SIZE = 1024  # pixels per side of a target's working resolution (`--size`)
MAX_COUNT = 1_000_000  # traces, targets, repeats, epochs, batch sizes, ...
MAX_PARTICLES = 100_000  # SMC particles of one run
MAX_WORKERS = 1024  # processes, threads, runs at once
MAX_MODULES = 10**9  # `--max-modules`
MAX_K = 64  # mixture components of a guide's continuous sites
MAX_HIDDEN = 4096  # hidden units per site network
MAX_CELL = 256  # pixels per cell of a contact sheet
MAX_COLUMNS = 100  # columns of a contact sheet
MAX_SHEET = 1000  # targets on one contact sheet
MAX_TIMEOUT = 86400.0  # seconds (`serve --timeout`)


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None


def integer(low: int, high: int, rule: str | None = None) -> Callable[[str], int]:
    """An argparse type: an integer from `low` to `high`; `rule` words the refusal."""

    def parse(text: str) -> int:
        value = _integer(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(
                f"{rule or f'must be from {low} to {high}'}, got {value}"
            )
        return value

    parse.__name__ = "integer"  # argparse names the type in some messages
    return parse


seed = integer(0, 2**63 - 1, "seeds are integers from 0 to 2**63 - 1")  # numpy: no negatives
render_size = integer(1, MAX_RENDER_SIZE, f"image sizes are 1 to {MAX_RENDER_SIZE} pixels")
target_size = integer(
    MIN_SIDE, MAX_TARGET_SIZE, f"target sizes are {MIN_SIDE} to {MAX_TARGET_SIZE} pixels"
)
count = integer(1, MAX_COUNT)
particles = integer(1, MAX_PARTICLES)
workers = integer(1, MAX_WORKERS)


def positive_number(high: float) -> Callable[[str], float]:
    """An argparse type: a number above 0 and at most `high` (no nan or inf)."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not 0 < value <= high:  # nan fails too
            raise argparse.ArgumentTypeError(
                f"must be a number above 0 and at most {high:g}, got {text}"
            )
        return value

    parse.__name__ = "number"
    return parse


def path(text: str) -> str:
    """A file or folder name; refuses the empty name (it would mean the current folder)."""
    if not text:
        raise argparse.ArgumentTypeError("an empty path")
    return text


def output_file(*suffixes: str) -> Callable[[str], str]:
    """An argparse type: a path to write, ending in one of `suffixes` (any case)."""

    def parse(text: str) -> str:
        if Path(path(text)).suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(
                f"the output must be a {' or '.join(suffixes)} file, got {text!r}"
            )
        return text

    parse.__name__ = "output file"
    return parse


def items(text: str) -> list[str]:
    """The items of a comma-separated list, stripped; refuses an empty list or item."""
    parts = [x.strip() for x in text.split(",")]
    if not any(parts):
        raise argparse.ArgumentTypeError("an empty list")
    if not all(parts):
        raise argparse.ArgumentTypeError(f"an empty item in the list {text!r}")
    return parts


def paths(text: str) -> tuple[str, ...]:
    """Comma-separated paths (several directories of traces or targets)."""
    return tuple(items(text))


def pairs(text: str) -> dict[str, str]:
    """NAME=PATH,... (a bare PATH is named after its file stem); names are unique."""
    from ngpm_compiler.evaluation.heldout import parse_pairs

    out: dict[str, str] = {}
    for item in items(text):
        name, eq, value = item.partition("=")
        if eq and not (name.strip() and value.strip()):
            raise argparse.ArgumentTypeError(f"{item!r}: expected NAME=PATH")
        ((name, value),) = parse_pairs(item).items()
        if name in out:
            raise argparse.ArgumentTypeError(f"the name {name!r} is given twice in {text!r}")
        out[name] = value
    return out


def integers(low: int, high: int) -> Callable[[str], tuple[int, ...]]:
    """An argparse type: comma-separated integers, each from `low` to `high`."""
    one = integer(low, high)

    def parse(text: str) -> tuple[int, ...]:
        return tuple(one(x) for x in items(text))

    parse.__name__ = "integers"
    return parse


def choices(allowed: Sequence[str], what: str) -> Callable[[str], tuple[str, ...]]:
    """An argparse type: a comma-separated subset of `allowed` (`what` names one)."""

    def parse(text: str) -> tuple[str, ...]:
        chosen = tuple(items(text))
        bad = [x for x in chosen if x not in allowed]
        if bad:
            raise argparse.ArgumentTypeError(
                f"unknown {what} {', '.join(bad)}; choose from {', '.join(allowed)}"
            )
        return chosen

    parse.__name__ = "choices"
    return parse


def _proposal(field: str, value: float) -> float:
    """`value` checked as ProposalSettings checks its `field` (one rule, kept there)."""
    from ngpm_runtime.errors import GuideError
    from ngpm_runtime.inference.guide import ProposalSettings

    try:
        ProposalSettings(**{field: value})
    except GuideError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    return value


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers like 1,0.5, got {text!r}") from None


def temperatures(text: str) -> tuple[float, ...]:
    """Comma-separated proposal temperatures (the range ProposalSettings allows)."""
    return tuple(_proposal("temperature", _number(x)) for x in items(text))


def ess_thresholds(text: str) -> tuple[float | None, ...]:
    """Comma-separated ESS thresholds, fractions of N in (0, 1], or 'none'."""
    return tuple(
        None if x.lower() == "none" else _proposal("ess_threshold", _number(x)) for x in items(text)
    )


def add_max_modules(parser: argparse.ArgumentParser) -> None:
    """The `--max-modules N` run option (the grammar's `max modules:` cap, overridden)."""
    parser.add_argument(
        "--max-modules",
        type=integer(1, MAX_MODULES),
        default=None,
        metavar="N",
        help="modules one particle may expand or interpret between two drawings before "
        "it stops with status limit (default: the grammar's 'max modules:', else "
        f"20000; at most {MAX_MODULES})",
    )


def add_workers(
    parser: argparse.ArgumentParser, default: int | None = 2, default_text: str = "2"
) -> None:
    """The `--workers N` option (processes)."""
    parser.add_argument(
        "--workers",
        type=workers,
        default=default,
        help=f"processes (default {default_text}, at most {MAX_WORKERS})",
    )


def add_target_size(parser: argparse.ArgumentParser) -> None:
    """The `--size N` option: a target's working resolution."""
    parser.add_argument(
        "--size",
        type=target_size,
        default=50,
        help=f"target size in pixels (default 50, {MIN_SIDE} to {MAX_TARGET_SIZE})",
    )


def limit_note(particle: FinalParticle, program: Program, max_modules: int | None) -> str | None:
    """One line saying which cap stopped `particle`, and how to raise it; None if none did."""
    if particle.status != "limit" or not particle.limit:
        return None
    from ngpm_runtime.inference.smc import module_cap

    if particle.limit == "max modules":
        return (
            f"status limit: max modules ({module_cap(program, max_modules)} modules "
            "expanded in one step without drawing); raise it with --max-modules or a "
            "'max modules:' line, or make the grammar draw sooner"
        )
    if particle.limit == "max primitives":
        return (
            f"status limit: max primitives ({program.max_primitives} drawn); raise it "
            "with a 'max primitives:' line"
        )
    return f"status limit: {particle.limit}"
