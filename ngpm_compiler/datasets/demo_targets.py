"""The demo's built-in targets (shipped in runtime/ngpm_runtime/data/): a glyph, a horse, a
heart and a spiral, and the 3D rows' vase mesh (`demo_vase.obj`). `write_demo_targets(dir)`
(re)makes them."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
from ngpm_runtime.files import atomic_write
from ngpm_runtime.image.targets import Target, auto_start, save_target
from PIL import Image, ImageDraw, ImageFont

SIZE = 50
SUPER = 8  # supersampling of the drawn shapes
VASE_FILE = "demo_vase.obj"


def _heart_mask(n: int) -> np.ndarray:
    t = np.linspace(0.0, 2 * math.pi, 400, endpoint=False)
    x = 16 * np.sin(t) ** 3
    y = 13 * np.cos(t) - 5 * np.cos(2 * t) - 2 * np.cos(3 * t) - np.cos(4 * t)
    pts = [
        (n / 2 + n * 0.028 * float(a), n / 2 - n * 0.028 * float(b))
        for a, b in zip(x, y, strict=True)
    ]
    img = Image.new("L", (n, n), 0)
    ImageDraw.Draw(img).polygon(pts, fill=255)
    return np.asarray(img) >= 128


def _spiral_mask(n: int) -> np.ndarray:
    th = np.linspace(0.0, 2.6 * math.pi, 600)
    r = n * (0.05 + 0.135 * th / math.pi)
    pts = [
        (n / 2 + float(rr * math.cos(a)), n / 2 - float(rr * math.sin(a)))
        for rr, a in zip(r, th, strict=True)
    ]
    img = Image.new("L", (n, n), 0)
    draw = ImageDraw.Draw(img)
    wid = int(round(0.075 * n))
    draw.line(pts, fill=255, width=wid, joint="curve")
    for x, y in (pts[0], pts[-1]):
        draw.ellipse((x - wid / 2, y - wid / 2, x + wid / 2, y + wid / 2), fill=255)
    return np.asarray(img) >= 128


def make_demo_targets(size: int = SIZE) -> dict[str, Target]:
    """The demo's targets: a glyph (DejaVu Sans Bold 'S'), scikit-image's horse, and a heart
    and a spiral drawn here; all framed like the datasets' silhouettes, automatic start."""
    from skimage.data import horse

    from ngpm_compiler.datasets.common import SUPERSAMPLE
    from ngpm_compiler.datasets.glyphs import default_font, render_glyph
    from ngpm_compiler.datasets.silhouettes import fit_mask

    face = ImageFont.truetype(str(default_font()), size * SUPERSAMPLE)
    masks = {
        "glyph": render_glyph(face, "S", size),
        "horse": fit_mask(~horse(), size)[0],
        "heart": fit_mask(_heart_mask(size * SUPER), size)[0],
        "spiral": fit_mask(_spiral_mask(size * SUPER), size)[0],
    }
    return {name: Target(m, auto_start(m), name) for name, m in masks.items()}


def vase_mesh(sides: int = 32, rings: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) of a closed vase, a solid of revolution about the y axis (y up,
    height 1): a round belly, a narrow neck and a flared lip, capped at both ends;
    triangles counter-clockwise seen from outside."""
    y = np.linspace(0.0, 1.0, rings)
    radius = 0.16 + 0.14 * np.sin(np.pi * np.minimum(y / 0.75, 1.0)) + 0.09 * (y / 1.0) ** 6
    a = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.stack(
        [
            radius[:, None] * np.cos(a),
            np.repeat(y[:, None], sides, 1),
            -radius[:, None] * np.sin(a),
        ],
        axis=-1,
    ).reshape(-1, 3)
    verts = np.concatenate([ring, [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    bottom, top = len(ring), len(ring) + 1
    tris = []
    for i in range(rings - 1):
        for j in range(sides):
            a0, a1 = i * sides + j, i * sides + (j + 1) % sides
            b0, b1 = a0 + sides, a1 + sides
            tris += [(a0, a1, b1), (a0, b1, b0)]
    last = (rings - 1) * sides
    for j in range(sides):
        k = (j + 1) % sides
        tris += [(bottom, k, j), (top, last + j, last + k)]
    return verts, np.array(tris, dtype=np.int64)


def vase_obj() -> str:
    """The vase as Wavefront .obj text (what `demo_vase.obj` holds)."""
    verts, tris = vase_mesh()
    lines = ["# the ngpm demo's vase (ngpm_compiler.datasets.demo_targets.vase_mesh)"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in tris]
    return "\n".join(lines) + "\n"


def write_demo_targets(out_dir: str | os.PathLike[str]) -> list[Path]:
    """Write `demo_<name>.png` + sidecar for every demo target and the vase mesh
    `demo_vase.obj` into out_dir."""
    written = [
        save_target(t, Path(out_dir) / f"demo_{name}.png")
        for name, t in make_demo_targets().items()
    ]
    return [*written, atomic_write(Path(out_dir) / VASE_FILE, vase_obj())]
