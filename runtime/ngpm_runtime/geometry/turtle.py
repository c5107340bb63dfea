"""The 2D turtle (architecture.md section 3) and primitive geometry.

Turtle state is a plain tuple `(x, y, heading_degrees, width)`; the push-down stack and the
open polygons are persistent cons lists `(head, rest)` / `None`, so a particle's turtle is
shared, never copied. Primitives are the plain tuples of section 8.
"""

from __future__ import annotations

import math
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


def interpret(
    mod: Module, turtle: Turtle, tstack: Cons | None, poly: Cons | None, angle: float
) -> tuple[Turtle, Cons | None, Cons | None, Prim | None]:
    """Apply one turtle symbol; returns (turtle, tstack, poly, primitive drawn or None).

    `poly` is a cons list of open polygons, each a cons list of vertices (newest first).
    """
    name = mod[0]
    x, y, h, w = turtle
    if name == "F":
        step = mod[1] if len(mod) > 1 else 1.0
        x1 = x + step * math.cos(h * _RAD)
        y1 = y + step * math.sin(h * _RAD)
        return (x1, y1, h, w), tstack, poly, ("seg", x, y, x1, y1, w)
    if name == "+":
        return (x, y, h + (mod[1] if len(mod) > 1 else angle), w), tstack, poly, None
    if name == "-":
        return (x, y, h - (mod[1] if len(mod) > 1 else angle), w), tstack, poly, None
    if name == "[":
        return turtle, (turtle, tstack), poly, None
    if name == "]":
        if tstack is None:
            raise ProgramError("turtle: ']' without a matching '['")
        return tstack[0], tstack[1], poly, None
    if name == "!":
        return (x, y, h, float(mod[1]) if len(mod) > 1 else w), tstack, poly, None
    if name == "f":
        step = mod[1] if len(mod) > 1 else 1.0
        return (
            (x + step * math.cos(h * _RAD), y + step * math.sin(h * _RAD), h, w),
            tstack,
            poly,
            None,
        )
    if name == "~l":
        length = float(mod[1]) if len(mod) > 1 else 1.0
        width = float(mod[2]) if len(mod) > 2 else 1.0
        return turtle, tstack, poly, ("leaf", x, y, h, length, width)
    if name == "@O":
        r = float(mod[1]) if len(mod) > 1 else 1.0
        return turtle, tstack, poly, ("disk", x, y, r)
    if name == "|":
        return (x, y, h + 180.0, w), tstack, poly, None
    if name == "{":
        return turtle, tstack, (None, poly), None
    if name == ".":
        if poly is None:
            return turtle, tstack, poly, None  # a vertex outside a polygon records nothing
        return turtle, tstack, (((x, y), poly[0]), poly[1]), None
    if name == "}":
        if poly is None:
            raise ProgramError("turtle: '}' without a matching '{'")
        verts = cons_to_list(poly[0])
        prim = ("poly", tuple(verts)) if len(verts) >= 3 else None
        return turtle, tstack, poly[1], prim
    return turtle, tstack, poly, None


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
