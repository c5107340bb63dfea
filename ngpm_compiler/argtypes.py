"""argparse value types shared by the `ngpmc` commands: bad values are refused while the
command line is parsed, with one line that names the option's rule."""

from __future__ import annotations

import argparse

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
