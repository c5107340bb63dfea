"""Meshes from 3D primitives (geometry/mesh.py), checked with trimesh as an independent
reader of the geometry: closed cylinders, mitred joints, leaves, polygons, spheres."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ngpm_runtime.geometry.mesh import (
    PALETTE,
    Mesh,
    MeshError,
    material_index,
    mesh_from_primitives,
)

trimesh = pytest.importorskip("trimesh")


def as_trimesh(mesh: Mesh):
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


def prism_area(r: float, sides: int) -> float:
    return 0.5 * sides * r * r * math.sin(2 * math.pi / sides)


def random_plant(n: int, seed: int = 0) -> list[tuple]:
    """Branches of segments that wander and fork, each starting where another ends."""
    rng = np.random.default_rng(seed)
    prims: list[tuple] = []
    tips = [(np.zeros(3), np.array([0.0, 1.0, 0.0]), 0.4)]
    while len(prims) < n:
        k = int(rng.integers(len(tips)))
        p, d, w = tips[k]
        d = d + rng.normal(0, 0.3, 3)
        d /= np.linalg.norm(d)
        q = p + 0.3 * d
        prims.append(("seg3", *p, *q, w, 0))
        if rng.random() < 0.15:
            tips.append((q, d, 0.8 * w))
        tips[k] = (q, d, 0.97 * w)
    return prims


def test_one_cylinder_is_closed_round_and_the_right_size() -> None:
    mesh = mesh_from_primitives([("seg3", 0, 0, 0, 0, 2, 0, 0.5, 0)])
    sides = 12  # radius 0.25 against a plant 2 long: the thickest class
    assert mesh.vertices.shape == (2 * sides, 3)
    assert mesh.faces.shape == (2 * sides + 2 * (sides - 2), 3)
    lo, hi = mesh.bounds
    assert lo[1] == 0 and hi[1] == 2
    assert np.allclose(np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 2]), 0.25)
    tm = as_trimesh(mesh)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume == pytest.approx(prism_area(0.25, sides) * 2, rel=1e-9)  # outward faces


def test_a_bend_shares_its_mitred_ring() -> None:
    turn = math.radians(60)
    end = (math.sin(turn), 1 + math.cos(turn), 0.0)
    mesh = mesh_from_primitives(
        [("seg3", 0, 0, 0, 0, 1, 0, 0.2, 0), ("seg3", 0, 1, 0, *end, 0.2, 0)]
    )
    sides = 12
    assert len(mesh.vertices) == 3 * sides  # start, shared joint, end
    tm = as_trimesh(mesh)
    assert tm.is_watertight and tm.is_winding_consistent
    # a mitred joint keeps the volume: cross-section times the centre line's length
    assert tm.volume == pytest.approx(prism_area(0.1, sides) * 2, rel=0.01)
    # the joint ring lies in the bisecting plane, on both cylinders
    joint = mesh.vertices[sides : 2 * sides] - np.array([0, 1, 0])
    normal = np.array([math.sin(turn), 1 + math.cos(turn), 0]) / math.hypot(
        math.sin(turn), 1 + math.cos(turn)
    )
    assert np.allclose(joint @ normal, 0, atol=1e-12)
    assert np.allclose(np.hypot(joint[:, 0], joint[:, 2]), 0.1)  # on the first cylinder


def test_a_plant_of_many_branches_is_closed() -> None:
    mesh = mesh_from_primitives(random_plant(400))
    tm = as_trimesh(mesh)
    assert tm.is_watertight and tm.is_winding_consistent and tm.volume > 0
    # most joints share a ring: far fewer vertices than two rings per segment
    assert len(mesh.vertices) < 1.3 * 400 * 8


def test_a_fork_continues_the_straightest_branch() -> None:
    prims = [
        ("seg3", 0, 0, 0, 0, 1, 0, 0.1, 0),
        ("seg3", 0, 1, 0, 1, 2, 0, 0.1, 0),  # the side branch, drawn first
        ("seg3", 0, 1, 0, 0, 2, 0, 0.1, 0),
    ]  # the continuation
    mesh = mesh_from_primitives(prims)
    sides = 12  # radius 0.05 of a plant 2.2 across: over 1%
    assert len(mesh.vertices) == 5 * sides  # 3 starts + 2 ends; the joint ring shared once
    assert as_trimesh(mesh).is_watertight


def test_a_sharp_turn_or_a_colour_change_caps_instead_of_sharing() -> None:
    back = mesh_from_primitives(
        [("seg3", 0, 0, 0, 0, 1, 0, 0.2, 0), ("seg3", 0, 1, 0, 0.1, 0, 0, 0.2, 0)]
    )  # turns > 120 deg
    colours = mesh_from_primitives(
        [("seg3", 0, 0, 0, 0, 1, 0, 0.2, 0), ("seg3", 0, 1, 0, 0, 2, 0, 0.2, 2)]
    )
    for mesh in (back, colours):
        assert len(mesh.vertices) == 4 * 12
        assert as_trimesh(mesh).is_watertight
    assert sorted(set(colours.face_material.tolist())) == [0, 2]


def test_sides_follow_the_radius() -> None:
    thin = mesh_from_primitives([("seg3", 0, 0, 0, 0, 100, 0, 0.1, 0)])
    mid = mesh_from_primitives([("seg3", 0, 0, 0, 0, 100, 0, 0.6, 0)])
    assert [len(m.vertices) // 2 for m in (thin, mid)] == [6, 8]


def test_leaf_is_a_double_sided_ellipse_along_h_and_l() -> None:
    mesh = mesh_from_primitives([("leaf3", 1, 2, 3, 0, 1, 0, 1, 0, 0, 2.0, 1.0, 0)])
    assert len(mesh.vertices) == 13 and len(mesh.faces) == 24
    lo, hi = mesh.bounds
    assert np.allclose(lo, [0.5, 2, 3]) and np.allclose(hi, [1.5, 4, 3])
    front, back = mesh.faces[:12], mesh.faces[12:]
    assert np.array_equal(back, front[:, ::-1])
    area = as_trimesh(mesh).area / 2
    assert area == pytest.approx(math.pi * 1.0 * 0.5, rel=0.06)  # inscribed 12-gon
    assert set(mesh.face_material.tolist()) == {1}  # colour 0: leaf green


def test_polygons_convex_and_concave() -> None:
    square = ("poly3", ((0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)), 0)
    ell = ("poly3", ((0, 0, 0), (2, 0, 0), (2, 1, 0), (1, 1, 0), (1, 2, 0), (0, 2, 0)), 0)
    for prim, tris, area in ((square, 2, 1.0), (ell, 4, 3.0)):
        mesh = mesh_from_primitives([prim])
        assert len(mesh.faces) == 2 * tris
        assert as_trimesh(mesh).area == pytest.approx(2 * area)  # both sides
    # a polygon given clockwise about +y (seen from above) meshes the same area
    mesh = mesh_from_primitives([("poly3", tuple(reversed(ell[1])), 0)])
    assert as_trimesh(mesh).area == pytest.approx(6.0)
    # fewer than three vertices, or all in a line: nothing
    assert len(mesh_from_primitives([("poly3", ((0, 0, 0), (1, 1, 1)), 0)]).faces) == 0
    assert len(mesh_from_primitives([("poly3", ((0, 0, 0), (1, 1, 1), (2, 2, 2)), 0)]).faces) == 0


def test_sphere_is_closed_and_centred() -> None:
    mesh = mesh_from_primitives([("sphere", 1, 2, 3, 0.5, 0)])
    lo, hi = mesh.bounds
    assert np.allclose((lo + hi) / 2, [1, 2, 3]) and hi[1] == pytest.approx(2.5)
    tm = as_trimesh(mesh)
    assert tm.is_watertight and tm.volume == pytest.approx(4 / 3 * math.pi / 8, rel=0.15)
    assert set(mesh.face_material.tolist()) == {7}  # colour 0: blossom


def test_colour_index_picks_the_palette() -> None:
    assert [material_index("seg3", c) for c in (0, 1, 3, 8, 9)] == [0, 1, 3, 0, 1]
    assert PALETTE[0].name == "bark" and PALETTE[1].name == "leaf"
    mesh = mesh_from_primitives(
        [("seg3", 0, 0, 0, 0, 1, 0, 0.2, 3), ("leaf3", 0, 1, 0, 0, 1, 0, 1, 0, 0, 1, 0.5, 5)]
    )
    assert set(mesh.face_material.tolist()) == {3, 5}
    vm = mesh.vertex_material()
    assert np.array_equal(vm[mesh.faces], np.repeat(mesh.face_material[:, None], 3, axis=1))


def test_refuses_2d_and_non_finite_primitives() -> None:
    with pytest.raises(MeshError, match="mesh output is for 3D grammars"):
        mesh_from_primitives([("seg", 0, 0, 1, 1, 0.1)])
    with pytest.raises(MeshError, match="not finite"):
        mesh_from_primitives([("seg3", 0, 0, 0, 0, math.inf, 0, 0.1, 0)])


def test_empty_and_degenerate_primitives_give_an_empty_mesh() -> None:
    mesh = mesh_from_primitives([("seg3", 1, 1, 1, 1, 1, 1, 0.1, 0), ("sphere", 0, 0, 0, 0, 0)])
    assert mesh.vertices.shape == (0, 3) and mesh.faces.shape == (0, 3)
    assert np.array_equal(mesh.bounds, np.zeros((2, 3)))


@pytest.mark.parametrize("spin_frames", [False, True])
def test_shared_rings_do_not_twist(monkeypatch: pytest.MonkeyPatch, spin_frames: bool) -> None:
    """A wandering branch keeps its cross-section: a twisted joint would pinch the tube
    (less volume; 15% less here with the ring offsets left out), even when each segment's
    own frame is spun at random about its axis."""
    import ngpm_runtime.geometry.mesh as mesh_module

    if spin_frames:
        frames = mesh_module._frames

        def spun(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            u, v = frames(d)
            t = np.random.default_rng(5).uniform(0, 2 * np.pi, len(d))[:, None]
            return u * np.cos(t) + v * np.sin(t), v * np.cos(t) - u * np.sin(t)

        monkeypatch.setattr(mesh_module, "_frames", spun)
    rng = np.random.default_rng(1)
    p, d = np.zeros(3), np.array([0.0, 1.0, 0.0])
    prims = []
    for _ in range(60):  # turns of 25 degrees about random axes
        axis = rng.normal(size=3)
        axis -= (axis @ d) * d
        axis /= np.linalg.norm(axis)
        d = d * math.cos(math.radians(25)) + np.cross(axis, d) * math.sin(math.radians(25))
        q = p + 0.5 * d
        prims.append(("seg3", *p, *q, 0.1, 0))
        p = q
    mesh = mesh_from_primitives(prims)
    sides = 8
    assert len(mesh.vertices) == 61 * sides  # every joint shared
    tm = as_trimesh(mesh)
    assert tm.is_watertight
    assert tm.volume == pytest.approx(prism_area(0.05, sides) * 30, rel=0.02)
    side_area = 2 * sides * 0.05 * math.sin(math.pi / sides) * 30
    assert tm.area == pytest.approx(side_area + 2 * prism_area(0.05, sides), rel=0.002)
