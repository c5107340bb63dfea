"""The 3D turtle (geometry/turtle3d.py): each rotation against hand-computed frames, `|`,
`$`, tropism, push/pop, the primitives, colour, and its place in derivation and SMC."""

import math

import numpy as np
import pytest
from fixtures.tiny_programs import make_program
from ngpm_runtime.errors import NgpmError, ProgramError
from ngpm_runtime.geometry.derive import Deriver
from ngpm_runtime.geometry.turtle import prim_bbox
from ngpm_runtime.geometry.turtle3d import (
    bend,
    bounds3d,
    interpret3d,
    prim3_bounds,
    project_xy,
    start3d,
)
from ngpm_runtime.inference.likelihood import CircuitLikelihood
from ngpm_runtime.inference.smc import SMCOptions, TraceRecording, forward, smc
from reference import turtle3d as ref3d

S30, C30 = 0.5, math.sqrt(3) / 2
UP = start3d(0.0, 0.0, 90.0)  # H = +Y, L = -X, U = +Z


def run(mods, turtle=UP, angle=90.0):
    """Interpret modules; returns (final turtle, primitives)."""
    tstack = poly = None
    prims = []
    for m in mods:
        turtle, tstack, poly, prim = interpret3d(m, turtle, tstack, poly, angle)
        if prim is not None:
            prims.append(prim)
    return turtle, prims


def frame(t):
    return np.array(t[3:6]), np.array(t[6:9]), np.array(t[9:12])


def assert_frame(t, h, lv, u) -> None:
    got = frame(t)
    for g, want in zip(got, (h, lv, u), strict=True):
        np.testing.assert_allclose(g, want, atol=1e-12)


def assert_orthonormal(t) -> None:
    h, lv, u = frame(t)
    np.testing.assert_allclose([h @ h, lv @ lv, u @ u], 1.0, atol=1e-12)
    np.testing.assert_allclose([h @ lv, h @ u, lv @ u], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.cross(h, lv), u, atol=1e-12)


def test_start_frame() -> None:
    assert UP[:12] == (0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    assert UP[12:] == (1.0, 0, None)
    east = start3d(2.0, 3.0, 0.0, 0.5)
    assert east[:12] == (2.0, 3.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    assert east[12] == 0.5
    t = start3d(0.0, 0.0, 30.0)
    assert_frame(t, (C30, S30, 0), (-S30, C30, 0), (0, 0, 1))


# symbol, angle -> H, L, U from the start frame H = +Y, L = -X, U = +Z
ROTATIONS = [
    ("+", 90.0, (-1, 0, 0), (0, -1, 0), (0, 0, 1)),  # turn left: H toward L
    ("-", 90.0, (1, 0, 0), (0, 1, 0), (0, 0, 1)),
    ("&", 90.0, (0, 0, -1), (-1, 0, 0), (0, 1, 0)),  # pitch down: H toward -U
    ("^", 90.0, (0, 0, 1), (-1, 0, 0), (0, -1, 0)),
    ("/", 90.0, (0, 1, 0), (0, 0, 1), (1, 0, 0)),  # roll right: L toward U
    ("\\", 90.0, (0, 1, 0), (0, 0, -1), (-1, 0, 0)),
    ("+", 30.0, (-S30, C30, 0), (-C30, -S30, 0), (0, 0, 1)),  # counter-clockwise from +Z
    ("-", 30.0, (S30, C30, 0), (-C30, S30, 0), (0, 0, 1)),
    ("&", 30.0, (0, C30, -S30), (-1, 0, 0), (0, S30, C30)),
    ("^", 30.0, (0, C30, S30), (-1, 0, 0), (0, -S30, C30)),
    ("/", 30.0, (0, 1, 0), (-C30, 0, S30), (S30, 0, C30)),
    ("\\", 30.0, (0, 1, 0), (-C30, 0, -S30), (-S30, 0, C30)),
]


@pytest.mark.parametrize(("sym", "a", "h", "lv", "u"), ROTATIONS)
def test_rotations_against_hand_computed_frames(sym, a, h, lv, u) -> None:
    t, _ = run([(sym, a)])
    assert_frame(t, h, lv, u)
    assert_orthonormal(t)
    assert t[:3] == UP[:3] and t[12:] == UP[12:]
    # without an argument the turtle turns by the `angle:` header's value
    t2, _ = run([(sym,)], angle=a)
    assert_frame(t2, h, lv, u)
    # the opposite symbol undoes it
    back = {"+": "-", "-": "+", "&": "^", "^": "&", "/": "\\", "\\": "/"}[sym]
    assert_frame(run([(sym, a), (back, a)])[0], (0, 1, 0), (-1, 0, 0), (0, 0, 1))


def test_turn_around_and_segments() -> None:
    t, prims = run([("&", 30.0), ("|",), ("!", 0.25), ("F", 2.0)])
    assert_frame(t, (0, -C30, S30), (1, 0, 0), (0, S30, C30))
    assert prims == [("seg3", 0.0, 0.0, 0.0, *t[:3], 0.25, 0)]
    np.testing.assert_allclose(t[:3], (0, -2 * C30, 2 * S30), atol=1e-12)
    t2, none = run([("f", 3.0)], t)
    assert none == [] and np.allclose(t2[:3], np.array(t[:3]) + 3 * np.array(t[3:6]))


def test_roll_to_horizontal() -> None:
    """`$`: L = V x H / |V x H| (V = +Y), U = H x L; H stays; a vertical H keeps the frame."""
    east = start3d(0.0, 0.0, 0.0)  # H = +X, L = +Y, U = +Z
    rolled, _ = run([("/", 37.0)], east)
    t, _ = run([("$",)], rolled)
    assert_frame(t, (1, 0, 0), (0, 0, -1), (0, 1, 0))
    assert run([("$",)])[0] == UP  # H vertical: nothing to do
    t, _ = run([("&", 50.0), ("+", 20.0), ("/", 70.0), ("$",)])
    h, lv, u = frame(t)
    want_h = frame(run([("&", 50.0), ("+", 20.0), ("/", 70.0)])[0])[0]
    np.testing.assert_allclose(h, want_h, atol=1e-12)
    assert abs(lv[1]) < 1e-12 and u[1] > 0  # L horizontal, U toward the sky
    np.testing.assert_allclose(
        lv, np.cross((0, 1, 0), h) / np.linalg.norm(np.cross((0, 1, 0), h)), atol=1e-12
    )
    assert_orthonormal(t)


def test_tropism_bends_heading_toward_t() -> None:
    """After each F, H turns about H x T by e |H x T| radians (ABOP p.58)."""
    e = 0.5
    east = start3d(0.0, 0.0, 0.0, tropism=(0.0, -1.0, 0.0, e))  # H = +X, T = -Y
    t, prims = run([("F", 1.0), ("F", 1.0)], east)
    # |H x T| = 1: the first segment goes along +X, then H = (cos e, -sin e, 0)
    assert prims[0][1:7] == (0.0, 0.0, 0.0, 1.0, 0.0, 0.0)
    np.testing.assert_allclose(prims[1][4:7], (1 + math.cos(e), -math.sin(e), 0), atol=1e-12)
    # the second F bends by e |H x T| = e cos(e) more
    a = e + e * math.cos(e)
    assert_frame(t, (math.cos(a), -math.sin(a), 0), (math.sin(a), math.cos(a), 0), (0, 0, 1))
    # a heading along T (or against it) is not bent; nor is anything without F
    assert (
        run([("F", 1.0)], start3d(0, 0, -90.0, tropism=(0, -1, 0, e)))[0][3:12]
        == start3d(0, 0, -90.0)[3:12]
    )
    assert run([("F", 1.0)], start3d(0, 0, 90.0, tropism=(0, -1, 0, e)))[0][3:12] == UP[3:12]
    assert run([("f", 1.0), ("+", 10.0)], east)[0][14] == (0.0, -1.0, 0.0, e)


def test_tropism_keeps_the_frame_orthonormal() -> None:
    rng = np.random.default_rng(0)
    d = np.array([0.3, -0.9, 0.3]) / math.sqrt(0.99)
    t = start3d(0.0, 0.0, 90.0, tropism=(*d.tolist(), 0.3))
    syms = ["+", "-", "&", "^", "/", "\\"]
    for _ in range(2000):
        t, _ = run([(syms[rng.integers(6)], float(rng.uniform(0, 180))), ("F", 0.1)], t)
    assert_orthonormal(t)
    # bend alone, with H at angle th from T: alpha = e sin(th)
    th, e = 0.7, 0.4
    t0 = start3d(0.0, 0.0, 0.0)
    t0 = t0[:3] + (math.sin(th), -math.cos(th), 0.0, math.cos(th), math.sin(th), 0.0) + t0[9:]
    b = bend(t0, (0.0, -1.0, 0.0, e))
    want = th - e * math.sin(th)
    np.testing.assert_allclose(b[3:6], (math.sin(want), -math.cos(want), 0), atol=1e-12)


def test_rotations_and_tropism_match_the_plain_reference_bit_for_bit() -> None:
    """The ops written out per axis give the same floats as tests/reference/turtle3d.py,
    so seeded 3D runs did not change with them."""
    rng = np.random.default_rng(1)
    d = np.array([0.2, -0.95, 0.1])
    trop = (*(d / np.linalg.norm(d)).tolist(), 0.35)
    t = start3d(1.0, 2.0, 33.0, tropism=trop)
    syms = ["+", "-", "&", "^", "/", "\\"]
    for k in range(3000):
        sym = syms[rng.integers(6)]
        a = float(rng.uniform(-200, 200))
        mod = (sym, a) if k % 3 else (sym,)  # the grammar's angle when no argument
        got, *_ = interpret3d(mod, t, None, None, 27.5)
        assert got == ref3d.rotate(t, sym, a if k % 3 else 27.5)
        assert bend(got, trop) == ref3d.bend(got, trop)
        t, _ = run([("F", 0.5)], got)  # moves, then bends
        assert t[3:12] == ref3d.bend(got, trop)[3:12]
    assert_orthonormal(t)


def test_push_pop_restores_everything() -> None:
    t, prims = run(
        [
            ("!", 0.5),
            (";",),
            ("[",),
            ("&", 40.0),
            ("!", 0.1),
            (";", 4.0),
            ("F", 1.0),
            ("]",),
            ("F", 1.0),
        ]
    )
    assert prims[1] == ("seg3", 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.5, 1)
    assert prims[0][-2:] == (0.1, 4)
    with pytest.raises(ProgramError, match="without a matching"):
        run([("]",)])
    with pytest.raises(ProgramError, match="without a matching"):
        run([("}",)])


def test_leaf_sphere_and_polygon_primitives() -> None:
    t, prims = run(
        [
            ("&", 90.0),
            (";",),
            ("~l", 2.0, 0.5),
            ("@O", 0.3),
            ("{",),
            (".",),
            ("f", 1.0),
            (".",),
            ("+", 90.0),
            ("f", 1.0),
            (".",),
            (";",),
            ("}",),
            ("{",),
            (".",),
            ("f", 1.0),
            (".",),
            ("}",),
        ]
    )
    # after & 90: H = -Z, L = -X, at the origin, colour 1
    assert prims[0][0] == "leaf3" and prims[0][-1] == 1
    np.testing.assert_allclose(prims[0][1:12], (0, 0, 0, 0, 0, -1, -1, 0, 0, 2.0, 0.5), atol=1e-12)
    assert prims[1] == ("sphere", 0.0, 0.0, 0.0, 0.3, 1)
    kind, verts, color = prims[2]
    assert (kind, color, len(prims)) == ("poly3", 2, 3)  # colour at `}`; 2 vertices: nothing
    np.testing.assert_allclose(verts, [(0, 0, 0), (0, 0, -1), (-1, 0, -1)], atol=1e-12)
    np.testing.assert_allclose(t[:3], (-2, 0, -1), atol=1e-12)


def test_colour_index() -> None:
    t, _ = run([(";",), (";",), (",",)])
    assert t[13] == 1
    assert run([(",",), (",",)])[0][13] == 0  # never below 0
    assert run([(";", 5.0)])[0][13] == 5 and run([(",", 2.7)])[0][13] == 2
    assert run([(";", -3.0)])[0][13] == 0
    with pytest.raises(ValueError):
        run([(";", float("nan"))])


def test_tropism_symbols() -> None:
    t, _ = run([("@Tp", 0.0, 0.0, -2.0)])
    assert t[14] == (0.0, 0.0, -1.0, 0.0)  # a unit direction; no elasticity yet
    t, _ = run([("@Ts", 0.3)], t)
    assert t[14] == (0.0, 0.0, -1.0, 0.3)
    assert run([("@Ts", 0.2)])[0][14] == (0.0, -1.0, 0.0, 0.2)  # gravity by default
    with pytest.raises(ValueError, match="no direction"):
        run([("@Tp", 0.0, 0.0, 0.0)])
    # popped with the rest of the state
    assert run([("[",), ("@Ts", 0.2), ("]",)])[0][14] is None


def test_bounds_and_projection() -> None:
    prims = [
        ("seg3", 0, 0, 0, 1, 2, 3, 0.5, 0),
        ("sphere", -1, 0, 1, 0.5, 0),
        ("leaf3", 0, 0, 0, 0, 0, -1, -1, 0, 0, 2.0, 0.5, 1),
        ("poly3", ((0, 0, 0), (1, 0, 0), (0, 5, 0)), 0),
    ]
    assert prim3_bounds(prims[0]) == (-0.25, -0.25, -0.25, 1.25, 2.25, 3.25)
    assert prim3_bounds(prims[2]) == (-0.25, 0.0, -2.0, 0.25, 0.0, 0.0)
    assert bounds3d(prims) == (-1.5, -0.5, -2.0, 1.25, 5.0, 3.25)
    assert bounds3d([]) is None
    for p in prims:  # SMC's 2D box of a 3D primitive: its x and y ranges
        b = prim3_bounds(p)
        assert prim_bbox(p) == (b[0], b[1], b[3], b[4])
    flat = project_xy(prims)
    assert flat[0] == ("seg", 0, 0, 1, 2, 0.5) and flat[1] == ("disk", -1, 0, 0.5)
    assert flat[3] == ("poly", ((0, 0), (1, 0), (0, 5)))
    leaf = np.array(flat[2][1])  # seen edge-on from +Z: a line along x of length 0.5
    np.testing.assert_allclose(leaf[:, 1], 0.0, atol=1e-12)
    np.testing.assert_allclose([leaf[:, 0].min(), leaf[:, 0].max()], [-0.25, 0.25], atol=1e-12)


# --- in derivation and SMC ------------------------------------------------------------------


def test_deriver_uses_the_3d_turtle_and_start_pose() -> None:
    prog = make_program(
        {},
        axiom=[("F", 1.0), ("&", 90.0), ("F", 2.0), ("Q",), (";",)],
        dim=3,
        start=(1.0, 2.0, 0.0),
    )
    got = forward(prog).primitives
    assert [(p[0], p[-2:]) for p in got] == [("seg3", (1.0, 0))] * 2
    np.testing.assert_allclose(
        [p[1:7] for p in got], [(1, 2, 0, 2, 2, 0), (2, 2, 0, 2, 2, -2)], atol=1e-12
    )
    assert forward(prog, start=(0.0, 0.0, 90.0)).primitives[0][1:7] == (0, 0, 0, 0, 1, 0)
    # a 2D program ignores the 3D-only symbols and its colour symbols
    flat = make_program({}, axiom=[("F", 1.0), ("&", 90.0), (";",), ("F", 2.0)])
    assert [p[0] for p in forward(flat).primitives] == ["seg", "seg"]
    with pytest.raises(ProgramError, match="dim must be 2 or 3"):
        Deriver(make_program({}, dim=4))


def test_header_tropism_reaches_the_turtle() -> None:
    prog = make_program(
        {},
        axiom=[("F", 1.0), ("F", 1.0)],
        dim=3,
        start=(0.0, 0.0, 0.0),
        tropism=(0.0, -1.0, 0.0, 0.5),
    )
    got = forward(prog).primitives
    np.testing.assert_allclose(got[1][4:7], (1 + math.cos(0.5), -math.sin(0.5), 0), atol=1e-12)


def test_3d_runs_into_a_picture_are_one_line_errors() -> None:
    """A 3D grammar grows into a 3D target (volume/, tests/runtime/volume): a picture's
    likelihood, or features without a 3D viewport to lay voxels over, are one-line errors."""
    prog = make_program({}, axiom=[("F", 1.0)], dim=3, viewport=(-1, 1, -1, 1))
    for run_it, says in (
        (lambda: smc(prog, CircuitLikelihood((-1, 1, -1, 1)), 2), "is a 2D likelihood"),
        (
            lambda: smc(prog, None, 2, options=SMCOptions(trace=TraceRecording.FULL)),
            "no 3D viewport",
        ),
    ):
        with pytest.raises(NgpmError) as err:
            run_it()
        assert "3D" in str(err.value) and says in str(err.value)
        assert "\n" not in str(err.value)
    assert smc(prog, None, 3).particles[0].primitives  # forward sampling works
