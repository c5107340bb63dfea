"""Shaded pictures of a mesh without a GPU or display: a numpy z-buffer rasterizer.

Orthographic view from azimuth `az` (degrees about the world's Y axis; 0 looks from +Z, so a
plant in the XY plane looks as its 2D render) and elevation `el` (degrees above the
horizon). Faces turned away from the viewer are culled (cylinders are closed, leaves and
polygons have both windings); each visible face gets one Lambert shade from a light above
and to the left of the viewer. Triangles are rasterized in batches of equal bounding-box
size (vectorized over triangles and pixels); the nearest face wins each pixel. Pictures are
drawn at twice the size and averaged down (anti-aliasing).
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ngpm_runtime.files import atomic_write
from ngpm_runtime.geometry.mesh_base import MeshData

DEFAULT_VIEW = (45.0, 20.0)  # a 3/4 view: azimuth, elevation in degrees
BACKGROUND = (255, 255, 255)
AMBIENT = 0.35
MARGIN = 0.05  # of the picture's side, around the plant
TILE = 32  # largest bounding box rasterized whole; bigger triangles are cut in tiles
CHUNK = 1 << 21  # candidate pixels per batch
GIF_SIZE, GIF_FRAMES = 256, 24


def _dot(v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Rows of v (n, 3) dotted with a (3,): plain numpy, as a threaded BLAS call for this
    shape is slow on a busy machine."""
    out: np.ndarray = v[:, 0] * a[0] + v[:, 1] * a[1] + v[:, 2] * a[2]
    return out


def view_axes(az: float, el: float) -> np.ndarray:
    """(3, 3): the screen's right, up, and the direction toward the viewer."""
    a, e = math.radians(az), math.radians(el)
    toward = np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
    right = np.array([math.cos(a), 0.0, -math.sin(a)])
    return np.stack([right, np.cross(toward, right), toward])


def _fit(projected: list[np.ndarray], size: int) -> tuple[float, np.ndarray]:
    """Scale and centre that fit every (n, 2) projection into a square of `size`."""
    pts = [p for p in projected if len(p)]
    if not pts:
        return 1.0, np.zeros(2)
    lo = np.min([p.min(axis=0) for p in pts], axis=0)
    hi = np.max([p.max(axis=0) for p in pts], axis=0)
    extent = float(np.max(hi - lo))
    scale = size * (1 - 2 * MARGIN) / extent if extent > 0 else 1.0
    return scale, (lo + hi) / 2


def _fit_turning(mesh: MeshData, views: list[np.ndarray], size: int) -> tuple[float, np.ndarray]:
    """Scale that fits the mesh in every view, and the box's middle (world), on which every
    view is centred (so a turning plant stays in place)."""
    if len(mesh.vertices) == 0:
        return 1.0, np.zeros(3)
    lo, hi = mesh.bounds
    mid: np.ndarray = (lo + hi) / 2
    half = max(float(np.abs(_dot(mesh.vertices - mid, d)).max()) for a in views for d in a[:2])
    return (size * (1 - 2 * MARGIN) / (2 * half) if half > 0 else 1.0), mid


@dataclass(frozen=True)
class _Faces:
    """What pictures from any view share: the faces with an area, their unit normals and
    material colours (RGB floats)."""

    faces: np.ndarray
    normals: np.ndarray
    rgb: np.ndarray


def _prepare(mesh: MeshData) -> _Faces:
    tri = mesh.vertices[mesh.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1)
    keep = length > 0
    rgb = np.array([m.rgb for m in mesh.materials], dtype=np.float64).reshape(-1, 3)
    return _Faces(
        mesh.faces[keep], normal[keep] / length[keep, None], rgb[mesh.face_material[keep]]
    )


def _shades(faces: _Faces, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Visible faces (indices) and their shaded RGB float colours."""
    visible = np.nonzero(_dot(faces.normals, axes[2]) > 0)[0]
    light = axes[2] * 0.8 + axes[1] * 0.5 - axes[0] * 0.35
    light /= np.linalg.norm(light)
    lambert = AMBIENT + (1 - AMBIENT) * np.clip(_dot(faces.normals[visible], light), 0.0, 1.0)
    return visible, faces.rgb[visible] * lambert[:, None]


Units = dict[tuple[int, int], tuple[np.ndarray, ...]]


def _units(x: np.ndarray, y: np.ndarray, h: int, w: int) -> Units:
    """Bounding boxes (pixel centres) of screen triangles (x, y: (t, 3)), clipped to the
    picture, grouped by tile size: {(width, height): (triangle, x0, y0, x1, y1)}; boxes
    over TILE pixels are cut into TILE x TILE tiles."""
    lo_x = np.minimum(np.minimum(x[:, 0], x[:, 1]), x[:, 2])  # faster than .min(axis=1)
    hi_x = np.maximum(np.maximum(x[:, 0], x[:, 1]), x[:, 2])
    lo_y = np.minimum(np.minimum(y[:, 0], y[:, 1]), y[:, 2])
    hi_y = np.maximum(np.maximum(y[:, 0], y[:, 1]), y[:, 2])
    x0 = np.maximum(np.ceil(lo_x - 0.5), 0).astype(np.int64)
    x1 = np.minimum(np.floor(hi_x - 0.5), w - 1).astype(np.int64)
    y0 = np.maximum(np.ceil(lo_y - 0.5), 0).astype(np.int64)
    y1 = np.minimum(np.floor(hi_y - 0.5), h - 1).astype(np.int64)
    t = np.nonzero((x1 >= x0) & (y1 >= y0))[0]
    x0, x1, y0, y1 = x0[t], x1[t], y0[t], y1[t]
    big = (x1 - x0 >= TILE) | (y1 - y0 >= TILE)
    if big.any():  # one unit per tile of each big box
        nx, ny = (x1[big] - x0[big]) // TILE + 1, (y1[big] - y0[big]) // TILE + 1
        rep = nx * ny
        k = np.arange(rep.sum()) - np.repeat(np.cumsum(rep) - rep, rep)
        tx = np.repeat(x0[big], rep) + TILE * (k % np.repeat(nx, rep))
        ty = np.repeat(y0[big], rep) + TILE * (k // np.repeat(nx, rep))
        t = np.concatenate([t[~big], np.repeat(t[big], rep)])
        x1 = np.concatenate([x1[~big], np.minimum(np.repeat(x1[big], rep), tx + TILE - 1)])
        y1 = np.concatenate([y1[~big], np.minimum(np.repeat(y1[big], rep), ty + TILE - 1)])
        x0, y0 = np.concatenate([x0[~big], tx]), np.concatenate([y0[~big], ty])
    # boxes rounded up to powers of two, wide and high apart (thin strips stay thin)
    key = np.ceil(np.log2(x1 - x0 + 1)).astype(np.int64) * 8 + np.ceil(np.log2(y1 - y0 + 1)).astype(
        np.int64
    )
    out: Units = {}
    for k in np.unique(key):
        sel = key == k
        out[(1 << int(k // 8), 1 << int(k % 8))] = (t[sel], x0[sel], y0[sel], x1[sel], y1[sel])
    return out


def _candidates(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, w: int, units: Units
) -> tuple[np.ndarray, ...]:
    """Pixels inside triangles: (pixel index, depth, triangle), over all units."""
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    out: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for (sw, sh), (tri, ux0, uy0, ux1, uy1) in units.items():
        step = max(1, CHUNK // (sw * sh))
        dx, dy = np.arange(sw * sh) % sw, np.arange(sw * sh) // sw
        for c in range(0, len(tri), step):
            t = tri[c : c + step]
            px = ux0[c : c + step, None] + dx
            py = uy0[c : c + step, None] + dy
            fx, fy = px + 0.5, py + 0.5
            ax, ay = x[t], y[t]
            inv = 1.0 / np.where(area[t] != 0, area[t], np.inf)[:, None]
            w0 = (
                (ax[:, 1:2] - fx) * (ay[:, 2:3] - fy) - (ax[:, 2:3] - fx) * (ay[:, 1:2] - fy)
            ) * inv
            w1 = (
                (ax[:, 2:3] - fx) * (ay[:, 0:1] - fy) - (ax[:, 0:1] - fx) * (ay[:, 2:3] - fy)
            ) * inv
            w2 = 1.0 - w0 - w1
            inside = (
                (w0 >= 0)
                & (w1 >= 0)
                & (w2 >= 0)
                & (inv != 0)
                & (px <= ux1[c : c + step, None])
                & (py <= uy1[c : c + step, None])
            )
            depth = w0 * z[t, 0:1] + w1 * z[t, 1:2] + w2 * z[t, 2:3]
            rows, cols = np.nonzero(inside)
            out.append(((py[rows, cols] * w + px[rows, cols]), depth[rows, cols], t[rows]))
    if not out:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
    return tuple(np.concatenate(parts) for parts in zip(*out, strict=True))


def _draw(
    vertices: np.ndarray,
    faces: _Faces,
    axes: np.ndarray,
    scale: float,
    centre: np.ndarray,
    h: int,
    w: int,
) -> np.ndarray:
    """RGB float picture (h, w, 3) of the faces seen along `axes`."""
    img = np.empty((h * w, 3), dtype=np.float32)
    img[:] = BACKGROUND
    if len(faces.faces) == 0:
        return img.reshape(h, w, 3)
    visible, color = _shades(faces, axes)
    sx = (_dot(vertices, axes[0]) - centre[0]) * scale + w / 2
    sy = h / 2 - (_dot(vertices, axes[1]) - centre[1]) * scale
    f = faces.faces[visible]
    x, y, z = sx[f], sy[f], _dot(vertices, axes[2])[f]
    pix, depth, tri = _candidates(x, y, z, w, _units(x, y, h, w))
    zbuf = np.full(h * w, -np.inf)
    np.maximum.at(zbuf, pix, depth)
    win = depth >= zbuf[pix]
    img[pix[win]] = color[tri[win]]
    return img.reshape(h, w, 3)


def _picture(
    vertices: np.ndarray,
    faces: _Faces,
    axes: np.ndarray,
    scale: float,
    centre: np.ndarray,
    size: int,
    s: int,
) -> np.ndarray:
    """_draw at s times the size, averaged down to uint8 (size, size, 3)."""
    img = _draw(vertices, faces, axes, scale * s, centre, size * s, size * s)
    blocks = img.reshape(size, s, size, s, 3)
    rows = sum((blocks[:, i] for i in range(1, s)), blocks[:, 0])  # faster than .mean
    small = sum((rows[:, :, j] for j in range(1, s)), rows[:, :, 0]) / np.float32(s * s)
    out: np.ndarray = np.clip(np.round(small), 0, 255).astype(np.uint8)
    return out


def render_mesh(
    mesh: MeshData, size: int = 512, view: tuple[float, float] | None = None, supersample: int = 2
) -> np.ndarray:
    """RGB uint8 (size, size, 3): the mesh from `view` (azimuth, elevation in degrees;
    default DEFAULT_VIEW), scaled to fit."""
    axes = view_axes(*(DEFAULT_VIEW if view is None else view))
    xy = np.stack([_dot(mesh.vertices, axes[0]), _dot(mesh.vertices, axes[1])], axis=1)
    scale, centre = _fit([xy], int(size))
    return _picture(
        mesh.vertices, _prepare(mesh), axes, scale, centre, int(size), max(1, int(supersample))
    )


def render_side_by_side(
    meshes: list[MeshData],
    size: int = 384,
    view: tuple[float, float] | None = None,
    supersample: int = 2,
) -> np.ndarray:
    """RGB uint8 (size, size * len(meshes), 3): the meshes from one `view`, drawn at one
    scale and centre (all fitted together) side by side, so they compare in place (a 3D
    target's voxels | the tree grown into it)."""
    axes = view_axes(*(DEFAULT_VIEW if view is None else view))
    xy = [np.stack([_dot(m.vertices, axes[0]), _dot(m.vertices, axes[1])], axis=1) for m in meshes]
    scale, centre = _fit(xy, int(size))
    pics = [
        _picture(m.vertices, _prepare(m), axes, scale, centre, int(size), max(1, supersample))
        for m in meshes
    ]
    return np.concatenate(pics, axis=1)


def save_png(rgb: np.ndarray, path: str | Path) -> Path:
    """An RGB uint8 picture written as a .png (atomically)."""
    return atomic_write(Path(path), _png(rgb))


def turntable(
    mesh: MeshData,
    frames: int = GIF_FRAMES,
    size: int = GIF_SIZE,
    view: tuple[float, float] | None = None,
    supersample: int = 2,
) -> list[np.ndarray]:
    """Pictures of the mesh turning once about the vertical axis, one scale for all."""
    az, el = DEFAULT_VIEW if view is None else view
    views = [view_axes(az + 360.0 * k / frames, el) for k in range(frames)]
    scale, mid = _fit_turning(mesh, views, int(size))
    faces = _prepare(mesh)
    return [
        _picture(
            mesh.vertices, faces, axes, scale, axes[:2] @ mid, int(size), max(1, int(supersample))
        )
        for axes in views
    ]


def _png(rgb: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG")
    return buf.getvalue()


def _gif(frames: list[np.ndarray], ms: int = 80) -> bytes:
    from PIL import Image

    pics = [Image.fromarray(f) for f in frames]
    palette = pics[0].quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    pics = [p.quantize(palette=palette, dither=Image.Dither.NONE) for p in pics]
    buf = io.BytesIO()
    pics[0].save(buf, format="GIF", save_all=True, append_images=pics[1:], duration=ms, loop=0)
    return buf.getvalue()


def save_picture(
    mesh: MeshData,
    path: str | Path,
    size: int | None = None,
    view: tuple[float, float] | None = None,
    frames: int = GIF_FRAMES,
) -> Path:
    """A .png picture (default 512 pixels) or a turntable .gif (`frames` pictures, default
    256 pixels) of the mesh, by the suffix."""
    path = Path(path)
    if path.suffix.lower() == ".gif":
        data = _gif(turntable(mesh, frames, size or GIF_SIZE, view))
    else:
        data = _png(render_mesh(mesh, size or 512, view))
    atomic_write(path, data)
    return path
