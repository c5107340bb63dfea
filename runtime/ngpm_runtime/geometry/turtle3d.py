"""The 3D turtle of ABOP chapter 1, cpfg and L-Py (docs/language.md section 4.1).

Turtle state is a plain tuple `(x, y, z, hx, hy, hz, lx, ly, lz, ux, uy, uz, width, color,
tropism)`: the position, the orthonormal frame H (heading), L (left), U (up) with
H x L = U, the width (a diameter), the colour index and the tropism `(tx, ty, tz, e)` (unit
direction, elasticity) or None. World Y is up. The start pose `(x, y, heading)` lies in the
XY plane: H = (cos h, sin h, 0), L = (-sin h, cos h, 0), U = (0, 0, 1), so `+` turns
counter-clockwise seen from +Z as in 2D, and a planar grammar seen from +Z is its 2D picture.
The push-down stack and the open polygons are persistent cons lists, as in `turtle.py`.

Primitives (plain tuples, world coordinates; the colour is an int index):

    ("seg3", x0, y0, z0, x1, y1, z1, width, color)      # width = diameter
    ("sphere", x, y, z, r, color)
    ("leaf3", x, y, z, hx, hy, hz, lx, ly, lz, length, width, color)
        # ellipse with its base at (x, y, z), long axis along the unit H (length), short
        # axis along the unit L (width)
    ("poly3", ((x, y, z), ...), color)                   # planar face, >= 3 vertices
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from ngpm_runtime.errors import ProgramError
from ngpm_runtime.geometry.cons import Cons, cons_to_list
from ngpm_runtime.program import Module

# as in turtle.py (which imports this module, so it imports nothing of turtle.py)
Prim = tuple[Any, ...]
Tropism = tuple[float, float, float, float]  # (tx, ty, tz) unit, elasticity e
Turtle3 = tuple[Any, ...]  # (x, y, z, H, L, U as 9 floats, width, color, tropism | None)

# Symbols the 3D turtle acts on; every other module is ignored by it.
TURTLE3D_SYMBOLS = frozenset(
    [
        "F",
        "f",
        "+",
        "-",
        "&",
        "^",
        "\\",
        "/",
        "|",
        "$",
        "[",
        "]",
        "!",
        "~l",
        "@O",
        "{",
        ".",
        "}",
        ";",
        ",",
        "@Tp",
        "@Ts",
    ]
)
GRAVITY = (0.0, -1.0, 0.0)  # the tropism direction `@Ts` uses when none was set
_RAD = math.pi / 180.0
_EPS = 1e-12


def _cos_sin(degrees: float) -> tuple[float, float]:
    """cos and sin of an angle in degrees, exact at multiples of 90 (a start pose)."""
    quarter = degrees / 90.0
    if quarter == int(quarter):
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[int(quarter) % 4]
    return math.cos(degrees * _RAD), math.sin(degrees * _RAD)


def start3d(
    x: float, y: float, heading: float, width: float = 1.0, tropism: Tropism | None = None
) -> Turtle3:
    """The 3D turtle at the 2D start pose (x, y, heading degrees), z = 0, colour 0."""
    c, s = _cos_sin(float(heading))
    return (float(x), float(y), 0.0, c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0, float(width), 0, tropism)


def interpret3d(
    mod: Module, turtle: Turtle3, tstack: Cons | None, poly: Cons | None, angle: float
) -> tuple[Turtle3, Cons | None, Cons | None, Prim | None]:
    """Apply one turtle symbol; returns (turtle, tstack, poly, primitive drawn or None), as
    `turtle.interpret` does in 2D. Rotations by `a` degrees (default `angle`): `+`/`-` about
    U (+ turns H toward L), `&`/`^` about L (& pitches H toward -U), `/`/`\\` about H (/ rolls
    L toward U). Each symbol's semantics is one function of TURTLE3D_OPS (the deriver calls
    them directly); any other module leaves the turtle as it is."""
    op = TURTLE3D_OPS.get(mod[0])
    if op is None:
        return turtle, tstack, poly, None
    return op(mod, turtle, tstack, poly, angle)


Step3 = tuple[Turtle3, Cons | None, Cons | None, Prim | None]  # what a symbol returns


def _turn_about(axis: str, sign: float) -> Callable[[Module, Turtle3, Any, Any, float], Step3]:
    """The op of a rotation symbol: the turtle turned by the symbol's angle (radians, times
    `sign`) about one frame axis, right-handed: about U, H -> H cos + L sin; about L,
    U -> U cos + H sin; about H, L -> L cos + U sin (the third vector p x q follows: p and q
    become p cos + q sin and q cos - p sin). One function per axis, written out: the deriver
    calls it for every turn (tests/reference/turtle3d.py holds the plain version)."""

    def about_u(mod: Module, t: Turtle3, tstack: Any, poly: Any, angle: float) -> Step3:
        a = (mod[1] if len(mod) > 1 else angle) * _RAD
        c, s = math.cos(a), sign * math.sin(a)
        p0, p1, p2, q0, q1, q2 = t[3:9]  # p = H, q = L
        p = (p0 * c + q0 * s, p1 * c + q1 * s, p2 * c + q2 * s)
        q = (q0 * c - p0 * s, q1 * c - p1 * s, q2 * c - p2 * s)
        return t[:3] + p + q + t[9:], tstack, poly, None

    def about_l(mod: Module, t: Turtle3, tstack: Any, poly: Any, angle: float) -> Step3:
        a = (mod[1] if len(mod) > 1 else angle) * _RAD
        c, s = math.cos(a), sign * math.sin(a)
        q0, q1, q2 = t[3:6]  # p = U, q = H
        p0, p1, p2 = t[9:12]
        h = (q0 * c - p0 * s, q1 * c - p1 * s, q2 * c - p2 * s)
        u = (p0 * c + q0 * s, p1 * c + q1 * s, p2 * c + q2 * s)
        return t[:3] + h + t[6:9] + u + t[12:], tstack, poly, None

    def about_h(mod: Module, t: Turtle3, tstack: Any, poly: Any, angle: float) -> Step3:
        a = (mod[1] if len(mod) > 1 else angle) * _RAD
        c, s = math.cos(a), sign * math.sin(a)
        p0, p1, p2, q0, q1, q2 = t[6:12]  # p = L, q = U
        p = (p0 * c + q0 * s, p1 * c + q1 * s, p2 * c + q2 * s)
        q = (q0 * c - p0 * s, q1 * c - p1 * s, q2 * c - p2 * s)
        return t[:6] + p + q + t[12:], tstack, poly, None

    return {"U": about_u, "L": about_l, "H": about_h}[axis]


def _push(mod: Module, turtle: Turtle3, tstack: Cons | None, poly: Cons | None, _: float) -> Step3:
    """`[`: push the turtle state."""
    return turtle, (turtle, tstack), poly, None


def _pop(mod: Module, turtle: Turtle3, tstack: Cons | None, poly: Cons | None, _: float) -> Step3:
    """`]`: pop the turtle state."""
    if tstack is None:
        raise ProgramError("turtle: ']' without a matching '['")
    return tstack[0], tstack[1], poly, None


def _move(mod: Module, t: Turtle3, tstack: Cons | None, poly: Cons | None, _: float) -> Step3:
    """`f`: move along H without drawing."""
    step = mod[1] if len(mod) > 1 else 1.0
    return (
        (t[0] + step * t[3], t[1] + step * t[4], t[2] + step * t[5]) + t[3:],
        tstack,
        poly,
        None,
    )


def _forward(
    mod: Module, t: Turtle3, tstack: Cons | None, poly: Cons | None, _: float = 0.0
) -> tuple[Turtle3, Cons | None, Cons | None, Prim | None]:
    """`F`: a segment from the turtle along H; then tropism bends the frame (ABOP p.58)."""
    step = mod[1] if len(mod) > 1 else 1.0
    x, y, z = t[0], t[1], t[2]
    x1, y1, z1 = x + step * t[3], y + step * t[4], z + step * t[5]
    moved = (x1, y1, z1) + t[3:]
    trop = t[14]
    if trop is not None and trop[3] != 0.0:
        moved = bend(moved, trop)
    return moved, tstack, poly, ("seg3", x, y, z, x1, y1, z1, t[12], t[13])


# rotation symbol -> (axis, sign): the frame vectors it turns and the sense
_AXES = {
    "+": ("U", 1.0),
    "-": ("U", -1.0),
    "&": ("L", 1.0),
    "^": ("L", -1.0),
    "/": ("H", 1.0),
    "\\": ("H", -1.0),
}


def _other(
    mod: Module, turtle: Turtle3, tstack: Cons | None, poly: Cons | None, _: float = 0.0
) -> tuple[Turtle3, Cons | None, Cons | None, Prim | None]:
    """The symbols other than moves, turns and brackets."""
    name = mod[0]
    t = turtle
    if name == "!":
        return t[:12] + (float(mod[1]) if len(mod) > 1 else t[12],) + t[13:], tstack, poly, None
    if name == "|":  # turn around: 180 degrees about U
        turned = (-t[3], -t[4], -t[5], -t[6], -t[7], -t[8])
        return t[:3] + turned + t[9:], tstack, poly, None
    if name == "$":
        return roll_horizontal(t), tstack, poly, None
    if name == "~l":
        length = float(mod[1]) if len(mod) > 1 else 1.0
        width = float(mod[2]) if len(mod) > 2 else 1.0
        return t, tstack, poly, ("leaf3",) + t[:9] + (length, width, t[13])
    if name == "@O":
        r = float(mod[1]) if len(mod) > 1 else 1.0
        return t, tstack, poly, ("sphere", t[0], t[1], t[2], r, t[13])
    if name in (";", ","):
        return t[:13] + (_color(mod, t[13]),) + t[14:], tstack, poly, None
    if name in ("{", ".", "}"):
        return _polygon(name, t, tstack, poly)
    if name == "@Tp":
        e = t[14][3] if t[14] is not None else 0.0
        return t[:14] + (_direction(mod[1], mod[2], mod[3]) + (e,),), tstack, poly, None
    if name == "@Ts":
        d = t[14][:3] if t[14] is not None else GRAVITY
        return t[:14] + (d + (float(mod[1]),),), tstack, poly, None
    return t, tstack, poly, None


# symbol -> its semantics: (mod, turtle, tstack, poly, angle) -> (turtle, tstack, poly, prim)
TURTLE3D_OPS: dict[str, Callable[[Module, Turtle3, Any, Any, float], Step3]] = {
    name: _other for name in TURTLE3D_SYMBOLS
}
TURTLE3D_OPS.update({"F": _forward, "f": _move, "[": _push, "]": _pop})
TURTLE3D_OPS.update({name: _turn_about(*_AXES[name]) for name in _AXES})


def _color(mod: Module, color: int) -> int:
    """`;` one colour up, `,` one down (not below 0); with an argument, that index."""
    if len(mod) > 1:
        v = float(mod[1])
        if not math.isfinite(v):
            raise ValueError(f"colour index {v}")
        return max(0, int(math.floor(v)))
    return color + 1 if mod[0] == ";" else max(0, color - 1)


def _direction(x: Any, y: Any, z: Any) -> tuple[float, float, float]:
    """The unit vector along (x, y, z); ValueError for a zero or non-finite one."""
    n = math.hypot(float(x), float(y), float(z))
    if not (n > 0 and math.isfinite(n)):
        raise ValueError(f"tropism direction ({x:g}, {y:g}, {z:g}) has no direction")
    return (x / n, y / n, z / n)


def _polygon(
    name: str, t: Turtle3, tstack: Cons | None, poly: Cons | None
) -> tuple[Turtle3, Cons | None, Cons | None, Prim | None]:
    """`{` opens a polygon, `.` records the turtle's position, `}` closes it (a planar face
    of >= 3 vertices, in the turtle's colour)."""
    if name == "{":
        return t, tstack, (None, poly), None
    if name == ".":
        if poly is None:
            return t, tstack, poly, None  # a vertex outside a polygon records nothing
        return t, tstack, (((t[0], t[1], t[2]), poly[0]), poly[1]), None
    if poly is None:
        raise ProgramError("turtle: '}' without a matching '{'")
    verts = cons_to_list(poly[0])
    prim = ("poly3", tuple(verts), t[13]) if len(verts) >= 3 else None
    return t, tstack, poly[1], prim


def roll_horizontal(t: Turtle3) -> Turtle3:
    """`$` (ABOP p.57): roll about H so that L is horizontal, L = V x H / |V x H| with V
    the world up (0, 1, 0), U = H x L. A vertical H leaves the frame as it is."""
    hx, hy, hz = t[3], t[4], t[5]
    n = math.sqrt(hz * hz + hx * hx)  # |V x H|, V x H = (hz, 0, -hx)
    if n < _EPS:
        return t
    lx, ly, lz = hz / n, 0.0, -hx / n
    u = (hy * lz - hz * ly, hz * lx - hx * lz, hx * ly - hy * lx)
    return t[:6] + (lx, ly, lz) + u + t[12:]


def bend(t: Turtle3, trop: Tropism) -> Turtle3:
    """Tropism (ABOP p.58): the frame turned about H x T by alpha = e |H x T| radians, which
    turns H toward T; then made orthonormal again (H unit, L unit and normal to H, U = H x
    L), so many bends do not let the frame drift."""
    hx, hy, hz = t[3], t[4], t[5]
    tx, ty, tz, e = trop
    ax, ay, az = hy * tz - hz * ty, hz * tx - hx * tz, hx * ty - hy * tx
    s = math.sqrt(ax * ax + ay * ay + az * az)
    if s < _EPS:
        return t
    alpha = e * s
    ax, ay, az = ax / s, ay / s, az / s
    c, sn = math.cos(alpha), math.sin(alpha)
    omc = 1.0 - c
    # Rodrigues on H and L: v cos + (a x v) sin + a (a . v)(1 - cos), written out
    d = (ax * hx + ay * hy + az * hz) * omc
    rx = hx * c + (ay * hz - az * hy) * sn + ax * d
    ry = hy * c + (az * hx - ax * hz) * sn + ay * d
    rz = hz * c + (ax * hy - ay * hx) * sn + az * d
    n = math.hypot(rx, ry, rz)
    if n == 0:
        raise ValueError("the turtle's frame has collapsed")
    h0, h1, h2 = rx / n, ry / n, rz / n
    vx, vy, vz = t[6], t[7], t[8]
    d = (ax * vx + ay * vy + az * vz) * omc
    lx = vx * c + (ay * vz - az * vy) * sn + ax * d
    ly = vy * c + (az * vx - ax * vz) * sn + ay * d
    lz = vz * c + (ax * vy - ay * vx) * sn + az * d
    dot = lx * h0 + ly * h1 + lz * h2
    lx, ly, lz = lx - dot * h0, ly - dot * h1, lz - dot * h2
    n = math.hypot(lx, ly, lz)
    if n == 0:
        raise ValueError("the turtle's frame has collapsed")
    l0, l1, l2 = lx / n, ly / n, lz / n
    return (
        t[:3]
        + (h0, h1, h2, l0, l1, l2)
        + (h1 * l2 - h2 * l1, h2 * l0 - h0 * l2, h0 * l1 - h1 * l0)
        + t[12:]
    )


def prim3_bounds(prim: Prim) -> tuple[float, float, float, float, float, float]:
    """World box `(xmin, ymin, zmin, xmax, ymax, zmax)` of a 3D primitive."""
    kind = prim[0]
    if kind == "seg3":
        _, x0, y0, z0, x1, y1, z1, w, _ = prim
        r = abs(w) / 2.0
        return (
            min(x0, x1) - r,
            min(y0, y1) - r,
            min(z0, z1) - r,
            max(x0, x1) + r,
            max(y0, y1) + r,
            max(z0, z1) + r,
        )
    if kind == "sphere":
        _, x, y, z, r, _ = prim
        r = abs(r)
        return x - r, y - r, z - r, x + r, y + r, z + r
    if kind == "leaf3":
        _, x, y, z, hx, hy, hz, lx, ly, lz, length, width, _ = prim
        a, b = length / 2.0, abs(width) / 2.0
        centre = (x + a * hx, y + a * hy, z + a * hz)
        ext = [
            math.sqrt((a * hv) ** 2 + (b * lv) ** 2) for hv, lv in ((hx, lx), (hy, ly), (hz, lz))
        ]
        lo = tuple(c - e for c, e in zip(centre, ext, strict=True))
        hi = tuple(c + e for c, e in zip(centre, ext, strict=True))
        return lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
    if kind == "poly3":
        xs, ys, zs = zip(*prim[1], strict=True)
        return min(xs), min(ys), min(zs), max(xs), max(ys), max(zs)
    raise ValueError(f"unknown 3D primitive {kind!r}")


def bounds3d(prims: list[Prim]) -> tuple[float, float, float, float, float, float] | None:
    """The world box `(xmin, ymin, zmin, xmax, ymax, zmax)` of 3D primitives (None: none)."""
    if not prims:
        return None
    boxes = [prim3_bounds(p) for p in prims]
    lo = [min(b[i] for b in boxes) for i in range(3)]
    hi = [max(b[i] for b in boxes) for i in range(3, 6)]
    return lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]


def project_xy(prims: list[Prim], points: int = 16) -> list[Prim]:
    """3D primitives seen from +Z (dropping z and colour) as 2D ones (`turtle.py`'s), for a
    picture of a 3D grammar: seg3 -> seg, sphere -> disk, leaf3 and poly3 -> poly (a leaf
    as `points` points of its ellipse)."""
    out: list[Prim] = []
    for p in prims:
        kind = p[0]
        if kind == "seg3":
            out.append(("seg", p[1], p[2], p[4], p[5], p[7]))
        elif kind == "sphere":
            out.append(("disk", p[1], p[2], p[4]))
        elif kind == "poly3":
            out.append(("poly", tuple((v[0], v[1]) for v in p[1])))
        elif kind == "leaf3":
            _, x, y, _, hx, hy, _, lx, ly, _, length, width, _ = p
            a, b = length / 2.0, width / 2.0
            ring = [
                (math.cos(2 * math.pi * k / points), math.sin(2 * math.pi * k / points))
                for k in range(points)
            ]
            out.append(
                (
                    "poly",
                    tuple(
                        (x + a * hx + a * c * hx + b * s * lx, y + a * hy + a * c * hy + b * s * ly)
                        for c, s in ring
                    ),
                )
            )
        else:
            raise ValueError(f"unknown 3D primitive {kind!r}")
    return out
