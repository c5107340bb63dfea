"""The 2D turtle (architecture.md section 3) and primitive geometry.

Turtle state is a plain tuple `(x, y, heading_degrees, width)`; the push-down stack and the
open polygons are persistent cons lists `(head, rest)` / `None`, so a particle's turtle is
shared, never copied. Primitives are the plain tuples of section 8.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ngpm_runtime.errors import ProgramError
from ngpm_runtime.geometry.cons import Cons, cons_to_list
from ngpm_runtime.geometry.turtle3d import prim3_bounds
from ngpm_runtime.program import Module

Turtle = tuple[float, float, float, float]  # (x, y, heading, width)
Prim = tuple[Any, ...]  # ("seg", x0, y0, x1, y1, width), ("disk", x, y, r), ...

# Symbols the turtle acts on; every other module is ignored by it.
TURTLE_SYMBOLS = frozenset(["F", "f", "+", "-", "|", "[", "]", "!", "~l", "@O", "{", ".", "}"])
# Symbols that may draw a primitive (resampling points).
DRAWING = frozenset(["F", "~l", "@O", "}"])
# Control symbols handled by the derivation itself.
CUT = "%"
HALT = "halt"

_RAD = math.pi / 180.0


Step = tuple[Turtle, Cons | None, Cons | None, Prim | None]  # what a symbol returns


def interpret(
    mod: Module, turtle: Turtle, tstack: Cons | None, poly: Cons | None, angle: float
) -> tuple[Turtle, Cons | None, Cons | None, Prim | None]:
    """Apply one turtle symbol; returns (turtle, tstack, poly, primitive drawn or None).

    `poly` is a cons list of open polygons, each a cons list of vertices (newest first).
    Each symbol's semantics is one function of TURTLE_OPS (the deriver calls them directly,
    from its dispatch table); any other module leaves the turtle as it is.
    """
    op = TURTLE_OPS.get(mod[0])
    if op is None:
        return turtle, tstack, poly, None
    return op(mod, turtle, tstack, poly, angle)


def _forward(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`F`: draw a segment of the current width; move forward."""
    x, y, h, w = t
    step = mod[1] if len(mod) > 1 else 1.0
    x1 = x + step * math.cos(h * _RAD)
    y1 = y + step * math.sin(h * _RAD)
    return (x1, y1, h, w), tstack, poly, ("seg", x, y, x1, y1, w)


def _left(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, angle: float) -> Step:
    """`+`: turn left (counter-clockwise) by `a` degrees (default `angle`)."""
    x, y, h, w = t
    return (x, y, h + (mod[1] if len(mod) > 1 else angle), w), tstack, poly, None


def _right(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, angle: float) -> Step:
    """`-`: turn right by `a` degrees (default `angle`)."""
    x, y, h, w = t
    return (x, y, h - (mod[1] if len(mod) > 1 else angle), w), tstack, poly, None


def _push(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`[`: push the turtle state."""
    return t, (t, tstack), poly, None


def _pop(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`]`: pop the turtle state."""
    if tstack is None:
        raise ProgramError("turtle: ']' without a matching '['")
    return tstack[0], tstack[1], poly, None


def _width(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`!(w)`: set the width."""
    x, y, h, w = t
    return (x, y, h, float(mod[1]) if len(mod) > 1 else w), tstack, poly, None


def _move(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`f`: move forward without drawing."""
    x, y, h, w = t
    step = mod[1] if len(mod) > 1 else 1.0
    return (
        (x + step * math.cos(h * _RAD), y + step * math.sin(h * _RAD), h, w),
        tstack,
        poly,
        None,
    )


def _leaf(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`~l(length, width)`: a leaf, base at the turtle, along the heading."""
    length = float(mod[1]) if len(mod) > 1 else 1.0
    width = float(mod[2]) if len(mod) > 2 else 1.0
    return t, tstack, poly, ("leaf", t[0], t[1], t[2], length, width)


def _disk(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`@O(r)`: a disk at the turtle."""
    r = float(mod[1]) if len(mod) > 1 else 1.0
    return t, tstack, poly, ("disk", t[0], t[1], r)


def _around(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`|`: turn around."""
    return (t[0], t[1], t[2] + 180.0, t[3]), tstack, poly, None


def _open(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`{`: start a polygon."""
    return t, tstack, (None, poly), None


def _vertex(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`.`: record a vertex of the open polygon (outside a polygon: nothing)."""
    if poly is None:
        return t, tstack, poly, None
    return t, tstack, (((t[0], t[1]), poly[0]), poly[1]), None


def _close(mod: Module, t: Turtle, tstack: Cons | None, poly: Cons | None, _: float) -> Step:
    """`}`: close and fill the polygon (>= 3 vertices)."""
    if poly is None:
        raise ProgramError("turtle: '}' without a matching '{'")
    verts = cons_to_list(poly[0])
    prim = ("poly", tuple(verts)) if len(verts) >= 3 else None
    return t, tstack, poly[1], prim


# symbol -> its semantics: (mod, turtle, tstack, poly, angle) -> (turtle, tstack, poly, prim)
TURTLE_OPS: dict[str, Callable[[Module, Turtle, Any, Any, float], Step]] = {
    "F": _forward,
    "f": _move,
    "+": _left,
    "-": _right,
    "|": _around,
    "[": _push,
    "]": _pop,
    "!": _width,
    "~l": _leaf,
    "@O": _disk,
    "{": _open,
    ".": _vertex,
    "}": _close,
}
assert frozenset(TURTLE_OPS) == TURTLE_SYMBOLS


def prim_bbox(prim: Prim) -> tuple[float, float, float, float]:
    """World bounding box `(xmin, ymin, xmax, ymax)` of a primitive (as raster.DrawBatch);
    of a 3D one (turtle3d.py), the box of its x and y ranges."""
    kind = prim[0]
    if kind == "seg":
        _, x0, y0, x1, y1, w = prim
        r = abs(w) / 2.0
        return min(x0, x1) - r, min(y0, y1) - r, max(x0, x1) + r, max(y0, y1) + r
    if kind == "disk":
        _, x, y, r = prim
        r = abs(r)
        return x - r, y - r, x + r, y + r
    if kind == "leaf":
        _, x, y, h, length, width = prim
        a, b = abs(length) / 2.0, abs(width) / 2.0
        c, s = math.cos(h * _RAD), math.sin(h * _RAD)
        cx, cy = x + length / 2.0 * c, y + length / 2.0 * s
        ex = math.sqrt((a * c) ** 2 + (b * s) ** 2)
        ey = math.sqrt((a * s) ** 2 + (b * c) ** 2)
        return cx - ex, cy - ey, cx + ex, cy + ey
    if kind == "poly":
        xs = [v[0] for v in prim[1]]
        ys = [v[1] for v in prim[1]]
        return min(xs), min(ys), max(xs), max(ys)
    if kind in ("seg3", "sphere", "leaf3", "poly3"):  # a 3D primitive: its box seen from +Z
        b = prim3_bounds(prim)
        return b[0], b[1], b[3], b[4]
    raise ValueError(f"unknown primitive {kind!r}")


def prim_params(prims: list[Prim]) -> np.ndarray:
    """The parameters of primitives of one kind (all but the kind), one row each."""
    return np.array([p[1:] for p in prims], dtype=np.float64)


def prim_bboxes(kind: str, prims: list[Prim]) -> tuple[np.ndarray, np.ndarray | None]:
    """World boxes (g, 4) as (xmin, ymin, xmax, ymax) of primitives of one kind, plus the
    kind's parameter array: `prim_bbox` for many primitives at once (the same formulas)."""
    if kind == "poly":
        out = np.empty((len(prims), 4))
        for k, p in enumerate(prims):
            v = np.asarray(p[1], dtype=np.float64).reshape(-1, 2)
            out[k] = v[:, 0].min(), v[:, 1].min(), v[:, 0].max(), v[:, 1].max()
        return out, None
    P = prim_params(prims)
    if kind == "seg":
        x0, y0, x1, y1, w = P.T
        r = np.abs(w) / 2.0
        box = [
            np.minimum(x0, x1) - r,
            np.minimum(y0, y1) - r,
            np.maximum(x0, x1) + r,
            np.maximum(y0, y1) + r,
        ]
    elif kind == "disk":
        x, y, r = P.T
        r = np.abs(r)
        box = [x - r, y - r, x + r, y + r]
    elif kind == "leaf":
        x, y, h, length, width = P.T
        c, s = np.cos(np.radians(h)), np.sin(np.radians(h))
        a, b = np.abs(length) / 2.0, np.abs(width) / 2.0
        cx, cy = x + length / 2.0 * c, y + length / 2.0 * s
        ex = np.sqrt((a * c) ** 2 + (b * s) ** 2)
        ey = np.sqrt((a * s) ** 2 + (b * c) ** 2)
        box = [cx - ex, cy - ey, cx + ex, cy + ey]
    else:
        raise ValueError(f"unknown primitive kind {kind!r}")
    return np.stack(box, axis=1), P
