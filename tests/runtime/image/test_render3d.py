"""Pictures of meshes (image/render3d.py): silhouettes where they belong, shading, depth,
turntable GIFs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ngpm_runtime.geometry.mesh import mesh_from_primitives
from ngpm_runtime.image.render3d import MARGIN, render_mesh, view_axes
from PIL import Image

CYLINDER = [("seg3", 0, 0, 0, 0, 2, 0, 0.5, 0)]
SPHERE = [("sphere", 0, 0, 0, 1, 0)]


def ink(img: np.ndarray) -> np.ndarray:
    return (img < 250).any(axis=2)


def span(mask: np.ndarray, axis: int) -> tuple[int, int]:
    idx = np.nonzero(mask.any(axis=axis))[0]
    return int(idx[0]), int(idx[-1])


def test_view_axes_are_a_right_handed_frame() -> None:
    for az, el in ((0, 0), (45, 20), (200, -70)):
        right, up, toward = view_axes(az, el)
        assert np.allclose(np.cross(right, up), toward)
        assert np.allclose([right @ right, up @ up, right @ up], [1, 1, 0])
    assert np.allclose(view_axes(0, 0), np.eye(3))  # from +Z: as the 2D picture


def test_vertical_cylinder_is_a_vertical_bar_in_the_middle() -> None:
    size = 100
    img = render_mesh(mesh_from_primitives(CYLINDER), size=size, view=(0, 0))
    assert img.shape == (size, size, 3)
    m = ink(img)
    top, bottom = span(m, 1)
    left, right = span(m, 0)
    assert top <= size * MARGIN + 1 and bottom >= size * (1 - MARGIN) - 2  # fits the height
    scale = size * (1 - 2 * MARGIN) / 2  # pixels per metre
    assert right - left + 1 == pytest.approx(0.5 * scale, abs=2)
    assert (left + right) / 2 == pytest.approx(size / 2 - 0.5, abs=1)
    assert m[top + 2 : bottom - 2, left + 1 : right].all()  # solid


def test_sphere_is_a_shaded_disk() -> None:
    size = 120
    img = render_mesh(mesh_from_primitives(SPHERE), size=size, view=(0, 0))
    m = ink(img)
    radius = size * (1 - 2 * MARGIN) / 2
    assert m.sum() == pytest.approx(np.pi * radius**2, rel=0.05)
    yy, xx = np.nonzero(m)
    assert np.hypot(yy.mean() - size / 2 + 0.5, xx.mean() - size / 2 + 0.5) < 1
    assert np.hypot(yy - size / 2, xx - size / 2).max() <= radius + 2
    # the light comes from above on the left: that side is brighter
    lum = img.astype(float).sum(axis=2)
    c, d = size // 2, int(radius * 0.5)
    assert lum[c - d, c - d] > lum[c + d, c + d] + 60


def test_nearer_faces_hide_farther_ones() -> None:
    mesh = mesh_from_primitives(
        [
            ("sphere", 0, 0, 1, 1, 1),  # leaf green, toward +Z
            ("sphere", 0, 0, -1, 1, 7),
        ]
    )  # blossom, toward -Z
    for az, nearer in ((0, "green"), (180, "pink")):
        r, g, b = render_mesh(mesh, size=64, view=(az, 0))[32, 32].astype(int)
        assert (g > r) == (nearer == "green"), (az, r, g, b)


def test_seen_from_above_a_cylinder_is_round() -> None:
    m = ink(render_mesh(mesh_from_primitives(CYLINDER), size=80, view=(0, 90)))
    top, bottom = span(m, 1)
    left, right = span(m, 0)
    assert abs((bottom - top) - (right - left)) <= 2


def test_leaf_shows_both_sides() -> None:
    mesh = mesh_from_primitives([("leaf3", 0, 0, 0, 0, 1, 0, 1, 0, 0, 2, 1, 0)])
    front = ink(render_mesh(mesh, size=64, view=(0, 0)))
    back = ink(render_mesh(mesh, size=64, view=(180, 0)))
    assert front.sum() > 500 and back.sum() == pytest.approx(front.sum(), rel=0.05)


def test_png_and_turntable_gif(tmp_path: Path) -> None:
    mesh = mesh_from_primitives([*CYLINDER, ("leaf3", 0, 1, 0, 1, 0, 0, 0, 1, 0, 1.5, 0.5, 0)])
    png = mesh.save(tmp_path / "p.png", size=64)
    with Image.open(png) as pic:
        assert pic.size == (64, 64) and ink(np.asarray(pic.convert("RGB"))).any()
    gif = mesh.save(tmp_path / "t.gif", size=48, frames=6)
    with Image.open(gif) as pic:
        assert pic.n_frames == 6 and pic.size == (48, 48)
        frames = []
        for k in range(6):
            pic.seek(k)
            frames.append(np.asarray(pic.convert("RGB")))
    assert not np.array_equal(frames[0], frames[1])  # it turns
    assert all(ink(f).any() for f in frames)


def test_empty_mesh_renders_blank() -> None:
    img = render_mesh(mesh_from_primitives([]), size=16)
    assert (img == 255).all()
