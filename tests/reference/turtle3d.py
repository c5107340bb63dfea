"""The 3D turtle's rotations and tropism written plainly (geometry/turtle3d.py writes them
out per axis, for speed): the tests' reference, with the same arithmetic in the same order,
so the frames are identical bit for bit."""

from __future__ import annotations

import math
from typing import Any

from ngpm_runtime.geometry.turtle3d import _AXES, _RAD

Turtle3 = tuple[Any, ...]


def rotate(t: Turtle3, name: str, degrees: float) -> Turtle3:
    """The turtle turned by a rotation symbol `name` by `degrees`."""
    axis, sign = _AXES[name]
    a = degrees * _RAD
    c, s = math.cos(a), sign * math.sin(a)
    h, lv, u = t[3:6], t[6:9], t[9:12]
    if axis == "U":  # p = H, q = L
        h, lv = _turn(h, lv, c, s)
    elif axis == "L":  # p = U, q = H
        u, h = _turn(u, h, c, s)
    else:  # p = L, q = U
        lv, u = _turn(lv, u, c, s)
    return t[:3] + h + lv + u + t[12:]


def _turn(
    p: tuple[float, ...], q: tuple[float, ...], c: float, s: float
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(p cos + q sin, q cos - p sin): p and q turned in their plane."""
    return (
        (p[0] * c + q[0] * s, p[1] * c + q[1] * s, p[2] * c + q[2] * s),
        (q[0] * c - p[0] * s, q[1] * c - p[1] * s, q[2] * c - p[2] * s),
    )


def bend(t: Turtle3, trop: tuple[float, float, float, float]) -> Turtle3:
    """Tropism: the frame turned about H x T by e |H x T| radians, then orthonormal again."""
    hx, hy, hz = t[3], t[4], t[5]
    tx, ty, tz, e = trop
    ax, ay, az = hy * tz - hz * ty, hz * tx - hx * tz, hx * ty - hy * tx
    s = math.sqrt(ax * ax + ay * ay + az * az)
    if s < 1e-12:
        return t
    alpha = e * s
    ax, ay, az = ax / s, ay / s, az / s
    c, sn = math.cos(alpha), math.sin(alpha)

    def rot(vx: float, vy: float, vz: float) -> tuple[float, float, float]:
        d = (ax * vx + ay * vy + az * vz) * (1.0 - c)
        return (
            vx * c + (ay * vz - az * vy) * sn + ax * d,
            vy * c + (az * vx - ax * vz) * sn + ay * d,
            vz * c + (ax * vy - ay * vx) * sn + az * d,
        )

    h = _unit(*rot(hx, hy, hz))
    lx, ly, lz = rot(t[6], t[7], t[8])
    dot = lx * h[0] + ly * h[1] + lz * h[2]
    lv = _unit(lx - dot * h[0], ly - dot * h[1], lz - dot * h[2])
    u = (h[1] * lv[2] - h[2] * lv[1], h[2] * lv[0] - h[0] * lv[2], h[0] * lv[1] - h[1] * lv[0])
    return t[:3] + h + lv + u + t[12:]


def _unit(x: float, y: float, z: float) -> tuple[float, float, float]:
    n = math.hypot(x, y, z)
    return (x / n, y / n, z / n)
