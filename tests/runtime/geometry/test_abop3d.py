"""The shipped 3D grammars against ABOP (The Algorithmic Beauty of Plants): figures 1.25 and
1.26 against a reference that rewrites ABOP's own production strings in parallel and draws
them with a rotation-matrix turtle (segment for segment, leaf for leaf), figure 2.8a's
branching angles, counts and tropism, and the stochastic tree."""

import math
import re
from collections import Counter

import numpy as np
import pytest
from ngpm_runtime.geometry.turtle3d import bounds3d
from ngpm_runtime.inference.smc import forward
from repo_paths import REPO

from ngpm_compiler.language.compile import compile_grammar

# ABOP's productions as printed (p.26 and p.27); ' is "next colour"
BUSH = {
    "A": "[&FL!A]/////'[&FL!A]///////'[&FL!A]",
    "F": "S/////F",
    "S": "FL",
    "L": "['''^^{-f+f+f-|-f+f+f}]",
}
PLANT = {
    "plant": "internode + [ plant + flower ] - - / / [ - - leaf ] internode [ + + leaf ] - "
    "[ plant flower ] + + plant flower",
    "internode": "F seg [ / / & & leaf ] [ / / ^ ^ leaf ] F seg",
    "seg": "seg F seg",
    "leaf": "[ ' { + f - f f - f + | + f - f f - f } ]",
    "flower": "[ & & & pedicel ' / wedge / / / / wedge / / / / wedge / / / / wedge / / / / wedge ]",
    "pedicel": "F F",
    "wedge": "[ ' ^ F ] [ { & & & & - f + f | - f + f } ]",
}


def rewrite(axiom: list[str], rules: dict[str, list[str]], n: int) -> list[str]:
    """Parallel rewriting, n steps."""
    word = axiom
    for _ in range(n):
        word = [t for s in word for t in rules.get(s, [s])]
    return word


def axis_rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    """Right-handed rotation matrix about a unit axis (Rodrigues' formula)."""
    a = math.radians(degrees)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * (k @ k)


def draw(word: list[str], delta: float) -> tuple[list, list]:
    """ABOP's 3D turtle by the symbols' names (p.19): + turn left (H toward L) about U,
    & pitch down about L, / roll right about H; within { } a vertex after each f.
    ' is the next colour. Returns segments (p0, p1, colour) and polygons (vertices,
    colour)."""
    pos, frame = np.zeros(3), np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]])  # H, L, U rows
    color = 0
    stack, segs, polys, verts = [], [], [], None
    turns = {"+": (2, 1), "-": (2, -1), "&": (1, 1), "^": (1, -1), "/": (0, 1), "\\": (0, -1)}
    for s in word:
        if s in turns:
            axis, sign = turns[s]
            frame = frame @ axis_rotation(frame[axis], sign * delta).T
        elif s == "|":
            frame = frame @ axis_rotation(frame[2], 180.0).T
        elif s in ("F", "f"):
            new = pos + frame[0]
            if s == "F":
                segs.append((pos, new, color))
            elif verts is not None:
                verts.append(new)
            pos = new
        elif s == "'":
            color += 1
        elif s == "[":
            stack.append((pos, frame, color))
        elif s == "]":
            pos, frame, color = stack.pop()
        elif s == "{":
            verts = []
        elif s == "}":
            polys.append((np.array(verts), color))
            verts = None
    return segs, polys


def ngpm(name: str, n: int | None = None) -> list:
    text = (REPO / "grammars" / f"{name}.lsys").read_text()
    if n is not None:
        text = re.sub(r"derivation length: \d+", f"derivation length: {n}", text)
    return forward(compile_grammar(text, filename=f"{name}.lsys").program()).primitives


def same_geometry(prims: list, segs: list, polys: list) -> None:
    """ngpm's segments and polygons are the reference's, in drawing order."""
    got_segs = [p for p in prims if p[0] == "seg3"]
    got_polys = [p for p in prims if p[0] == "poly3"]
    assert len(got_segs) == len(segs) and len(got_polys) == len(polys)
    np.testing.assert_allclose(
        [p[1:7] for p in got_segs], [np.concatenate(s[:2]) for s in segs], atol=1e-9
    )
    assert [p[8] for p in got_segs] == [s[2] for s in segs]
    for p, (verts, color) in zip(got_polys, polys, strict=True):
        np.testing.assert_allclose(np.array(p[1]), verts, atol=1e-9)
        assert p[2] == color


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_bush_figure_1_25_matches_abop(n: int) -> None:
    rules = {k: list(v) for k, v in BUSH.items()}
    word = rewrite(["A"], rules, n)
    segs, polys = draw(word, 22.5)
    same_geometry(ngpm("bush3d", n), segs, polys)


def test_bush_figure_1_25_counts_at_n_7() -> None:
    """n = 7 as in the figure: the segments and leaves of ABOP's string."""
    word = rewrite(["A"], {k: list(v) for k, v in BUSH.items()}, 7)
    prims = ngpm("bush3d")
    kinds = Counter(p[0] for p in prims)
    assert kinds == {"seg3": word.count("F"), "poly3": word.count("{")}
    assert (kinds["seg3"], kinds["poly3"]) == (3891, 1284)


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_plant_figure_1_26_matches_abop(n: int) -> None:
    rules = {k: v.split() for k, v in PLANT.items()}
    segs, polys = draw(rewrite(["plant"], rules, n), 18.0)
    same_geometry(ngpm("plant3d", n), segs, polys)


def test_tree_figure_2_8a_branching() -> None:
    """ABOP fig. 2.8a: a vertical trunk of 200 lr^6 (tropism T = -Y does not bend it), three
    branches leaving it at the branching angle a = 18.95 from the vertical, divergence
    angles d1 = 94.74 and d2 = 132.63 between them, 1 + 2 (3^6 - 1) segments, and branches
    that droop: with e = 0.22 the segments end lower than without tropism."""
    prims = ngpm("tree3d")
    assert len(prims) == 1 + 2 * (3**6 - 1) and {p[0] for p in prims} == {"seg3"}
    trunk = prims[0]
    np.testing.assert_allclose(trunk[1:7], (0, 0, 0, 0, 200 * 1.109**6, 0), atol=1e-9)
    assert trunk[7] == pytest.approx(1.732**6)
    top = np.array(prims[1][4:7])  # the end of A's first F(50)
    firsts = [p for p in prims if np.allclose(p[1:4], top) and p is not prims[1]][:3]
    dirs = [np.array(p[4:7]) - top for p in firsts]
    for d in dirs:
        assert math.degrees(math.acos(d[1] / np.linalg.norm(d))) == pytest.approx(18.95)
    az = [math.degrees(math.atan2(d[2], d[0])) for d in dirs]
    gaps = sorted(abs((b - a + 180) % 360 - 180) for a, b in zip(az, az[1:] + az[:1], strict=True))
    assert gaps == pytest.approx(sorted([94.74, 132.63, 360 - 94.74 - 132.63]))
    text = (REPO / "grammars" / "tree3d.lsys").read_text()
    straight = compile_grammar(
        text.replace("tropism: 0 -1 0 0.22", "tropism: 0 -1 0 0"), filename="tree3d.lsys"
    ).program()
    unbent = forward(straight).primitives
    assert np.mean([p[5] for p in prims]) < np.mean([p[5] for p in unbent]) - 100
    assert bounds3d(prims)[0] < bounds3d(unbent)[0]  # and spread wider


def test_stochastic_tree_is_seeded_and_varies() -> None:
    program = compile_grammar(REPO / "grammars" / "stochastic_tree3d.lsys").program()
    assert program.dim == 3 and len(program.sites) == 9
    a, b = forward(program, seed=1), forward(program, seed=2)
    assert a.primitives == forward(program, seed=1).primitives
    assert a.primitives != b.primitives and a.status == b.status == "done"
    assert math.isfinite(a.log_prior) and {p[0] for p in a.primitives} == {"seg3"}
