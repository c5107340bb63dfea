"""How much of a picture's shape survives the reduction to the working size, and which size
would keep it: thin strokes vanish when a large picture shrinks to 50 x 50."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

MIN_SIDE = 8  # smallest accepted picture side and working size, in pixels
KEEP_WARNING = 0.6  # below this share of the shape kept, grow warns and suggests a size
KEEP_GOOD = 0.8  # a suggested size keeps at least this share
SIZES = (64, 100, 128, 160, 200)  # sizes to suggest, smallest first


def shape_kept(square: np.ndarray, small: np.ndarray) -> float:
    """Share of the full-size square mask's shape pixels that lie in shape cells of the
    reduced mask `small` (1.0 when the square is empty)."""
    square = np.asarray(square, dtype=bool)
    total = int(square.sum())
    if total == 0:
        return 1.0
    side, n = square.shape[0], small.shape[0]
    idx = (np.arange(side) * n) // side  # the cell of each full-size row / column
    covered = np.asarray(small, dtype=bool)[idx[:, None], idx[None, :]]
    return float((square & covered).sum()) / total


def suggest_size(
    square: np.ndarray, resize: Callable[[np.ndarray, int], np.ndarray], current: int
) -> int | None:
    """The smallest size in SIZES above `current` that keeps KEEP_GOOD of the shape, where
    `resize(square, size)` is the loader's reduction; None when none does (or the picture
    is smaller than those sizes)."""
    side = np.asarray(square).shape[0]
    for size in SIZES:
        if current < size <= side and shape_kept(square, resize(square, size)) >= KEEP_GOOD:
            return size
    return None


def fit_note(kept: float, suggested: int | None, size: int) -> str:
    """What to tell a user whose picture lost shape at `size` x `size`."""
    return (
        f"only {kept:.0%} of the picture's shape is kept at {size} x {size} pixels "
        f"(thin strokes vanish when it is reduced): {fit_fix(suggested)}"
    )


def fit_fix(suggested: int | None) -> str:
    """What to do about a picture that loses its shape at the working size."""
    if suggested:
        return (
            f"draw thicker strokes, or grow at --size {suggested} (guides trained at "
            "50 x 50 guide less well there)"
        )
    return "draw thicker strokes (or a bigger shape)"


def check_fit(
    square: np.ndarray, small: np.ndarray, resize: Callable[[np.ndarray, int], np.ndarray]
) -> tuple[float, int | None]:
    """(share kept, a better size or None) of reducing `square` to `small`; the size is
    looked for only when less than KEEP_WARNING is kept."""
    kept = shape_kept(square, small)
    if kept >= KEEP_WARNING:
        return kept, None
    return kept, suggest_size(square, resize, small.shape[0])
