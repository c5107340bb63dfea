"""The `envelopes` set: targets a grammar can reach, made from its own forward samples.

Each target is one forward sample rasterized at the target size in the grammar's viewport,
closed (dilated, then eroded) into a filled silhouette, with the sample's start pose as the
target's start. A bounded plant (a bush of fixed size growing up from its base) cannot fill
generic strokes, but it can fill shapes of its own kind: `ngpmc learn` trains on these when
unguided SMC reaches the generic targets too poorly (experiments/learn.py).
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from ngpm_runtime.errors import NgpmError
from ngpm_runtime.geometry.turtle import Prim
from ngpm_runtime.image.raster import rasterize
from ngpm_runtime.image.targets import Target
from ngpm_runtime.program import Program

from ngpm_compiler.datasets.common import DatasetError, Item

BATCH = 10  # forward samples per SMC run (no likelihood: independent samples)
CLOSE_PX = 3.0  # closing radius in pixels at 50 x 50 (scaled with the size)
MIN_INK = 0.03  # share of the canvas an envelope must cover to be kept
MAX_TRIES = 20  # samples drawn per target kept, at most, before giving up


def grammar_sha(path: str | os.PathLike[str]) -> str:
    """The grammar file's sha256 (what a build's index records)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def disk(radius: int) -> list[tuple[int, int]]:
    """The (dy, dx) offsets of a disk of `radius` pixels."""
    r = radius
    span = range(-r, r + 1)
    return [(dy, dx) for dy in span for dx in span if dy * dy + dx * dx <= r * r + r]


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """`mask` dilated by a disk (outside the image counts as unset)."""
    if radius <= 0:
        return mask.copy()
    h, w = mask.shape
    p = np.pad(mask, radius)
    out = np.zeros_like(mask)
    for dy, dx in disk(radius):
        out |= p[radius + dy : radius + dy + h, radius + dx : radius + dx + w]
    return out


def close(mask: np.ndarray, radius: int) -> np.ndarray:
    """Morphological closing by a disk: gaps narrower than about 2 * radius filled. The
    image is padded first, so shapes touching the border keep their border pixels."""
    if radius <= 0:
        return mask.copy()
    pad = radius + 1
    p = np.pad(np.asarray(mask, dtype=bool), pad)
    closed = ~dilate(~dilate(p, radius), radius)
    return closed[pad:-pad, pad:-pad]


def start_of(program: Program) -> tuple[float, float, float, float]:
    """The grammar's start pose as a target's start (normalized image x, y, then the
    heading's dx, dy in image axes)."""
    assert program.viewport is not None
    xmin, xmax, ymin, ymax = (float(v) for v in program.viewport)
    x, y, heading = (float(v) for v in program.start[:3])
    a = math.radians(heading)
    return ((x - xmin) / (xmax - xmin), (ymax - y) / (ymax - ymin), math.cos(a), -math.sin(a))


def envelope(prims: list[Prim], program: Program, size: int) -> np.ndarray:
    """The filled silhouette of one sample's primitives at size x size."""
    assert program.viewport is not None
    img = rasterize(prims, program.viewport, size, size) > 0
    return close(img, max(1, round(CLOSE_PX * size / 50)))


def _program(grammar: str | os.PathLike[str] | None) -> Program:
    from ngpm_compiler.language.compile import load_grammar

    if grammar is None:
        raise DatasetError("envelopes are made from a grammar's samples: give --grammar FILE")
    if not Path(grammar).is_file():
        raise DatasetError(f"{grammar}: no such grammar file")
    program = load_grammar(Path(grammar))
    if program.dim != 2:
        raise DatasetError(f"{grammar}: a 3D grammar; envelopes are 2D targets")
    if program.viewport is None:
        raise DatasetError(
            f"{grammar}: no 'viewport:' line to draw its samples in (`ngpmc check` proposes one)"
        )
    start = start_of(program)
    if not (0.0 <= start[0] <= 1.0 and 0.0 <= start[1] <= 1.0):
        raise DatasetError(f"{grammar}: its start pose lies outside its viewport")
    return program


def build_envelopes(
    count: int, seed: int, size: int, grammar: str | os.PathLike[str] | None = None, **_: object
) -> Iterator[Item]:
    """`count` envelopes of the grammar's forward samples (batch b seeded [seed, b]);
    samples whose envelope covers less than MIN_INK of the canvas are skipped. The start
    pixel may lie off the ink: a stem thinner than a pixel draws nothing at this size."""
    from ngpm_runtime.inference.smc import SMCOptions, smc

    program = _program(grammar)
    start = start_of(program)
    made, drawn, b = 0, 0, 0
    while made < count:
        if drawn >= 5 * BATCH and drawn > MAX_TRIES * made:  # under 1 in MAX_TRIES kept
            raise DatasetError(
                f"{grammar}: {drawn - made} of {drawn} forward samples drew too little "
                f"(envelope under {MIN_INK:.0%} of the canvas); fit the viewport to what it draws"
            )
        seq = np.random.SeedSequence([seed, b])
        options = SMCOptions(seed=int(seq.generate_state(1, np.uint64)[0] >> 1), ess_threshold=0.5)
        try:
            res = smc(program, None, BATCH, options=options)
        except NgpmError as err:
            raise DatasetError(f"{grammar}: forward samples failed: {err}") from None
        for k, particle in enumerate(res.particles):
            drawn += 1
            mask = envelope(list(particle.primitives), program, size)
            if mask.mean() < MIN_INK or made >= count:
                continue
            what = f"{len(particle.primitives)} primitives, ink {mask.mean():.0%}"
            yield Target(mask, start, "envelopes"), f"envelope {made} (sample {b}.{k}, {what})"
            made += 1
        b += 1
