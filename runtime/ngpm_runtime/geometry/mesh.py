"""Triangle meshes from 3D primitives: cylinders, leaves, polygons and spheres, in numpy.

The 3D turtle's primitives are plain tuples in world coordinates (Y up, metres):
    ("seg3", x0, y0, z0, x1, y1, z1, width, color)   # width = diameter
    ("sphere", x, y, z, r, color)
    ("leaf3", x, y, z, hx, hy, hz, lx, ly, lz, length, width, color)
    ("poly3", ((x, y, z), ...), color)
`mesh_from_primitives(prims)` builds one `Mesh` from them, each kind in one vectorized pass.

Segments are cylinders with a round cross-section of 6, 8 or 12 sides (by the radius
against the plant's size). Joints have no gaps: where a segment starts at the end of
another, going on within 120 degrees, the two meet on their mitre plane (the plane that
bisects the turn), so each cylinder is cut where the other begins. Consecutive segments of
the same sides and colour share that ring (a generalized cylinder: the branch tapers from
one width to the next along a segment); ends that share no ring are capped. Shared rings
rather than spheres at the joints: no extra triangles, a smooth surface, and half the
vertices; spheres would triple the triangle count of a twig.

Leaves are ellipses and polygons are planar faces, written with both windings (double-sided
in every format and viewer, with back faces culled). Polygons are triangulated as fans
when convex and by ear clipping when not.

Colours: the colour index selects a material of `PALETTE`; index 0 (the turtle's default)
is the kind's own: bark for segments, leaf green for leaves and polygons, blossom for
spheres. Index c > 0 is `PALETTE[c % 8]`: 1 leaf, 2 dark bark, 3 pale wood, 4 young leaf,
5 dark leaf, 6 autumn yellow, 7 blossom, 8 bark again.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ngpm_runtime.geometry.mesh_base import PALETTE as PALETTE
from ngpm_runtime.geometry.mesh_base import Material as Material
from ngpm_runtime.geometry.mesh_base import MeshData as MeshData
from ngpm_runtime.geometry.mesh_base import MeshError as MeshError
from ngpm_runtime.geometry.mesh_files import save_mesh
from ngpm_runtime.image.render3d import render_mesh

Prim = tuple[Any, ...]

KIND_DEFAULT = {"seg3": 0, "leaf3": 1, "poly3": 1, "sphere": 7}  # material of colour 0
SIDES = (12, 8, 6)  # cylinder sides, thick to thin
SIDE_STEPS = (0.01, 0.002)  # radius / plant size from which a cylinder gets 12, then 8 sides
MAX_TURN = 120.0  # degrees: sharper joints are capped, not mitred
LEAF_POINTS = 12  # vertices on a leaf's outline
SPHERE_LON, SPHERE_LAT = 12, 6


class Mesh(MeshData):
    """A `MeshData` that saves (`save`) and draws itself (`render`)."""

    def save(
        self,
        path: str | Path,
        size: int | None = None,
        view: tuple[float, float] | None = None,
        frames: int | None = None,
    ) -> Path:
        """Write .glb, .obj (+ .mtl), .ply, a .png picture or a turntable .gif, by the
        suffix (`size`, `view` and `frames` are for the pictures; mesh_files.save_mesh)."""
        return save_mesh(self, path, size=size, view=view, frames=frames)

    def render(self, size: int = 512, view: tuple[float, float] | None = None) -> np.ndarray:
        """A shaded RGB picture (size, size, 3) uint8 (image.render3d.render_mesh)."""
        return render_mesh(self, size=size, view=view)


def material_index(kind: str, color: Any) -> int:
    c = int(color)
    return KIND_DEFAULT[kind] if c == 0 else c % len(PALETTE)


def _materials(kind: str, colors: np.ndarray) -> np.ndarray:
    """material_index for an array of colour indices."""
    c = colors.astype(np.int64)
    out: np.ndarray = np.where(c == 0, KIND_DEFAULT[kind], c % len(PALETTE))
    return out


def _finite(arr: np.ndarray, kind: str) -> None:
    if not np.isfinite(arr).all():
        raise MeshError(f"a {kind} primitive has a coordinate that is not finite")


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    out: np.ndarray = v / np.where(n > 0, n, 1.0)
    return out


def _frames(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors u, v with (u, v, d) right-handed, for unit directions d (n, 3)."""
    axis = np.zeros_like(d)
    axis[np.arange(len(d)), np.argmin(np.abs(d), axis=1)] = 1.0
    u = _unit(np.cross(d, axis))
    return u, np.cross(d, u)


def _point_ids(points: np.ndarray) -> np.ndarray:
    """An id per row of (n, 3) float64 points: equal ids for bitwise-equal points."""
    rows = np.ascontiguousarray(points + 0.0)  # -0.0 -> 0.0
    keys = rows.view(np.dtype((np.void, rows.dtype.itemsize * 3))).ravel()
    _, ids = np.unique(keys, return_inverse=True)
    out: np.ndarray = ids.ravel()
    return out


def _best_per(keys: np.ndarray, score: np.ndarray) -> np.ndarray:
    """Indices of the pairs with the highest score for each key (the first on ties)."""
    order = np.lexsort((-score, keys))
    first = np.ones(len(order), dtype=bool)
    first[1:] = keys[order][1:] != keys[order][:-1]
    out: np.ndarray = order[first]
    return out


def _link(p0: np.ndarray, p1: np.ndarray, d: np.ndarray) -> np.ndarray:
    """succ (n,): the segment that goes on from each segment's end (-1: none): one that
    starts where it ends, turning at most MAX_TURN degrees, the straightest; each segment
    continues at most one."""
    n = len(p0)
    ids = _point_ids(np.concatenate([p0, p1]))
    start_id, end_id = ids[:n], ids[n:]
    order = np.argsort(start_id, kind="stable")
    counts = np.bincount(start_id, minlength=2 * n)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    per = np.minimum(counts[end_id], 16)  # candidates per segment (bounded)
    i = np.repeat(np.arange(n), per)
    k = np.arange(len(i)) - np.repeat(np.cumsum(per) - per, per)
    j = order[first[end_id[i]] + k]
    cos = np.einsum("ij,ij->i", d[i], d[j])
    ok = (j != i) & (cos >= math.cos(math.radians(MAX_TURN)))
    i, j, cos = i[ok], j[ok], cos[ok]
    best = _best_per(i, cos)
    i, j, cos = i[best], j[best], cos[best]
    best = _best_per(j, cos)
    succ = np.full(n, -1, dtype=np.int64)
    succ[i[best]] = j[best]
    return succ


def _project(
    ring: np.ndarray, center: np.ndarray, along: np.ndarray, normal: np.ndarray
) -> np.ndarray:
    """Move ring points (m, S, 3) along `along` (m, 3) onto the plane through `center`
    with `normal` (m, 3)."""
    dist = np.einsum("msk,mk->ms", ring - center[:, None], normal)
    den = np.einsum("mk,mk->m", along, normal)
    out: np.ndarray = ring - along[:, None] * (dist / den[:, None])[:, :, None]
    return out


def _ring(
    center: np.ndarray, u: np.ndarray, v: np.ndarray, r: np.ndarray, sides: int
) -> np.ndarray:
    a = 2 * np.pi * np.arange(sides) / sides
    out: np.ndarray = center[:, None] + r[:, None, None] * (
        np.cos(a)[None, :, None] * u[:, None] + np.sin(a)[None, :, None] * v[:, None]
    )
    return out


def _fan(ring: np.ndarray, reverse: bool) -> np.ndarray:
    """Triangles (m, S-2, 3) closing rings of vertex indices (m, S)."""
    s = ring.shape[1]
    a, b = ring[:, 1 : s - 1], ring[:, 2:]
    first = np.broadcast_to(ring[:, :1], a.shape)
    out: np.ndarray = np.stack([first, b, a] if reverse else [first, a, b], axis=-1)
    return out


class _Builder:
    """Vertices and faces collected kind by kind."""

    def __init__(self) -> None:
        self.vertices: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.materials: list[np.ndarray] = []
        self.count = 0

    def reserve(self, verts: np.ndarray) -> int:
        """Append vertices (k, 3); returns the index of the first."""
        base = self.count
        self.vertices.append(verts.reshape(-1, 3))
        self.count += len(self.vertices[-1])
        return base

    def add_faces(self, faces: np.ndarray, material: np.ndarray) -> None:
        self.faces.append(faces.reshape(-1, 3))
        self.materials.append(np.broadcast_to(material, faces.shape[:-1]).ravel())

    def mesh(self) -> Mesh:
        if not self.faces:
            return Mesh(
                np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
            )
        return Mesh(
            np.concatenate(self.vertices, dtype=np.float64),
            np.concatenate(self.faces, dtype=np.int64),
            np.concatenate(self.materials, dtype=np.int64),
        )


def _segments(b: _Builder, segs: list[Prim]) -> None:
    """Cylinders for ("seg3", ...) tuples, joined along branches (module docstring)."""
    arr = np.array([s[1:9] for s in segs], dtype=np.float64).reshape(-1, 8)
    _finite(arr, "seg3")
    mat = _materials("seg3", arr[:, 7])
    p0, p1, r = arr[:, 0:3], arr[:, 3:6], np.abs(arr[:, 6]) / 2
    length = np.linalg.norm(p1 - p0, axis=1)
    keep = (length > 0) & (r > 0)
    p0, p1, r, mat, length = p0[keep], p1[keep], r[keep], mat[keep], length[keep]
    n = len(p0)
    if n == 0:
        return
    d = (p1 - p0) / length[:, None]
    u, v = _frames(d)
    size = float(np.linalg.norm(np.ptp(np.concatenate([p0, p1]), axis=0))) or 1.0
    cls = np.searchsorted(-np.array(SIDE_STEPS), -r / size, side="left")
    sides = np.array(SIDES)[cls]
    succ = _link(p0, p1, d)
    has = succ >= 0
    pred = np.full(n, -1, dtype=np.int64)
    pred[succ[has]] = np.nonzero(has)[0]
    shared = has & (sides[np.maximum(succ, 0)] == sides) & (mat[np.maximum(succ, 0)] == mat)
    # mitre planes: the start's with the predecessor, the end's with the successor
    n_start = np.where((pred >= 0)[:, None], _unit(d[np.maximum(pred, 0)] + d), d)
    n_end = np.where(has[:, None], _unit(d + d[np.maximum(succ, 0)]), d)
    # start rings first, for every segment, so a successor's ring index is known
    start_base = np.zeros(n, dtype=np.int64)
    for s in SIDES:
        idx = np.nonzero(sides == s)[0]
        ring = _project(_ring(p0[idx], u[idx], v[idx], r[idx], s), p0[idx], d[idx], n_start[idx])
        start_base[idx] = b.reserve(ring) + s * np.arange(len(idx))
    for s in SIDES:
        idx = np.nonzero(sides == s)[0]
        if len(idx):
            _cylinder_faces(b, s, idx, start_base, succ, shared, pred, p1, d, u, v, r, n_end, mat)


def _cylinder_faces(
    b: _Builder,
    s: int,
    idx: np.ndarray,
    start_base: np.ndarray,
    succ: np.ndarray,
    shared: np.ndarray,
    pred: np.ndarray,
    p1: np.ndarray,
    d: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    r: np.ndarray,
    n_end: np.ndarray,
    mat: np.ndarray,
) -> None:
    """Sides and caps of the cylinders `idx`, all of `s` sides."""
    k = np.arange(s)
    start = start_base[idx][:, None] + k  # (m, s)
    end = np.empty_like(start)
    sh = shared[idx]
    own = idx[~sh]
    ring = _project(_ring(p1[own], u[own], v[own], r[own], s), p1[own], d[own], n_end[own])
    end[~sh] = b.reserve(ring) + s * np.arange(len(own))[:, None] + k
    i, j = idx[sh], succ[idx[sh]]
    # the successor's ring vertex nearest to this segment's angle 0 (no twist)
    q = _project(u[i][:, None], np.zeros_like(u[i]), d[i], n_end[i])[:, 0]
    w = q - d[j] * np.einsum("mk,mk->m", q, d[j])[:, None]
    phi = np.arctan2(np.einsum("mk,mk->m", w, v[j]), np.einsum("mk,mk->m", w, u[j]))
    off = np.round(phi * s / (2 * np.pi)).astype(np.int64)
    end[sh] = start_base[j][:, None] + (k + off[:, None]) % s
    nxt = np.roll(start, -1, axis=1), np.roll(end, -1, axis=1)
    sides = np.stack(
        [np.stack([start, nxt[0], nxt[1]], axis=-1), np.stack([start, nxt[1], end], axis=-1)],
        axis=2,
    )
    b.add_faces(sides, mat[idx][:, None, None])
    capped = pred[idx] < 0
    capped |= ~shared[np.maximum(pred[idx], 0)]
    b.add_faces(_fan(start[capped], reverse=True), mat[idx][capped][:, None])
    b.add_faces(_fan(end[~sh], reverse=False), mat[idx][~sh][:, None])


def _leaves(b: _Builder, leaves: list[Prim]) -> None:
    """Ellipses for ("leaf3", ...) tuples: both windings (double-sided)."""
    arr = np.array([p[1:13] for p in leaves], dtype=np.float64).reshape(-1, 12)
    _finite(arr, "leaf3")
    mat = _materials("leaf3", arr[:, 11])
    base, h, lat = arr[:, 0:3], _unit(arr[:, 3:6]), _unit(arr[:, 6:9])
    a, w = np.abs(arr[:, 9]) / 2, np.abs(arr[:, 10]) / 2
    keep = (a > 0) & (w > 0)
    base, h, lat, a, w, mat = base[keep], h[keep], lat[keep], a[keep], w[keep], mat[keep]
    m = len(base)
    if m == 0:
        return
    center = base + h * a[:, None]
    t = 2 * np.pi * np.arange(LEAF_POINTS) / LEAF_POINTS
    outline = (
        center[:, None]
        + (a[:, None] * np.cos(t))[:, :, None] * h[:, None]
        + (w[:, None] * np.sin(t))[:, :, None] * lat[:, None]
    )
    first = b.reserve(np.concatenate([center[:, None], outline], axis=1))
    c = first + (LEAF_POINTS + 1) * np.arange(m)[:, None]  # (m, 1) centre index
    ring = c + 1 + np.arange(LEAF_POINTS)
    nxt = np.roll(ring, -1, axis=1)
    cc = np.broadcast_to(c, ring.shape)
    front = np.stack([cc, ring, nxt], axis=-1)
    b.add_faces(np.concatenate([front, front[..., ::-1]], axis=1), mat[:, None])


def _sphere_template() -> tuple[np.ndarray, np.ndarray]:
    """Unit UV sphere: vertices (T, 3) and outward faces."""
    lat = np.pi * np.arange(1, SPHERE_LAT) / SPHERE_LAT
    lon = 2 * np.pi * np.arange(SPHERE_LON) / SPHERE_LON
    y = np.repeat(np.cos(lat), SPHERE_LON)
    rad = np.repeat(np.sin(lat), SPHERE_LON)
    ring = np.stack(
        [rad * np.sin(np.tile(lon, len(lat))), y, rad * np.cos(np.tile(lon, len(lat)))], axis=1
    )
    verts = np.concatenate([[[0.0, 1.0, 0.0]], ring, [[0.0, -1.0, 0.0]]])
    bottom = len(verts) - 1
    faces = []
    k = np.arange(SPHERE_LON)
    k1 = (k + 1) % SPHERE_LON
    faces.append(np.stack([np.zeros_like(k), 1 + k, 1 + k1], axis=1))
    for band in range(SPHERE_LAT - 2):
        top, low = 1 + band * SPHERE_LON, 1 + (band + 1) * SPHERE_LON
        faces.append(np.stack([top + k, low + k, low + k1], axis=1))
        faces.append(np.stack([top + k, low + k1, top + k1], axis=1))
    last = 1 + (SPHERE_LAT - 2) * SPHERE_LON
    faces.append(np.stack([np.full_like(k, bottom), last + k1, last + k], axis=1))
    return verts, np.concatenate(faces)


def _spheres(b: _Builder, spheres: list[Prim]) -> None:
    arr = np.array([p[1:6] for p in spheres], dtype=np.float64).reshape(-1, 5)
    _finite(arr, "sphere")
    mat = _materials("sphere", arr[:, 4])
    keep = np.abs(arr[:, 3]) > 0
    arr, mat = arr[keep], mat[keep]
    if len(arr) == 0:
        return
    tv, tf = _sphere_template()
    first = b.reserve(arr[:, None, :3] + np.abs(arr[:, 3])[:, None, None] * tv)
    faces = first + len(tv) * np.arange(len(arr))[:, None, None] + tf
    b.add_faces(faces, mat[:, None])


def _newell(pts: np.ndarray) -> np.ndarray:
    """Normals (m, 3) of polygons (m, k, 3), not normalized (Newell's method)."""
    out: np.ndarray = np.cross(pts, np.roll(pts, -1, axis=1)).sum(axis=1)
    return out


def _polygons(b: _Builder, polys: list[Prim]) -> None:
    """Planar faces for ("poly3", vertices, color): grouped by vertex count, convex ones
    fanned in one pass, concave ones ear-clipped one by one."""
    groups: dict[int, list[Prim]] = {}
    for p in polys:
        if len(p[1]) >= 3:
            groups.setdefault(len(p[1]), []).append(p)
    for k, group in sorted(groups.items()):
        pts = np.array([p[1] for p in group], dtype=np.float64).reshape(-1, k, 3)
        colors = np.array([p[2] for p in group], dtype=np.float64)
        _finite(pts, "poly3")
        _finite(colors, "poly3")
        mat = _materials("poly3", colors)
        normal = _newell(pts)
        flat = np.linalg.norm(normal, axis=1) > 0
        pts, mat, normal = pts[flat], mat[flat], normal[flat]
        if len(pts) == 0:
            continue
        edge = np.roll(pts, -1, axis=1) - pts
        turn = np.einsum("mkc,mc->mk", np.cross(edge, np.roll(edge, -1, axis=1)), normal)
        convex = (turn >= 0).all(axis=1)
        first = b.reserve(pts) + k * np.arange(len(pts))
        ring = first[:, None] + np.arange(k)
        fan = _fan(ring[convex], reverse=False)
        b.add_faces(np.concatenate([fan, fan[..., ::-1]], axis=1), mat[convex][:, None])
        for m in np.nonzero(~convex)[0]:
            tris = ring[m][_ear_clip(pts[m], normal[m])]
            b.add_faces(np.concatenate([tris, tris[:, ::-1]]), mat[m])


def _ear_clip(pts: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Triangles (k - 2, 3) of local indices for a simple planar polygon (k, 3) whose
    vertices go counter-clockwise about `normal`."""
    axis = int(np.argmax(np.abs(normal)))
    xy = np.delete(pts, axis, axis=1)
    if normal[axis] * (-1 if axis == 1 else 1) < 0:  # (x, z) is seen from -y
        xy = xy[:, ::-1]
    live = list(range(len(pts)))
    tris: list[tuple[int, int, int]] = []

    def cross(o: int, a: int, c: int) -> float:
        return float(
            (xy[a, 0] - xy[o, 0]) * (xy[c, 1] - xy[o, 1])
            - (xy[a, 1] - xy[o, 1]) * (xy[c, 0] - xy[o, 0])
        )

    guard = 0
    while len(live) > 3 and guard < 4 * len(pts) ** 2:
        guard += 1
        for n in range(len(live)):
            a, o, c = live[n - 1], live[n], live[(n + 1) % len(live)]
            if cross(a, o, c) <= 0:
                continue
            inside = any(
                cross(a, o, q) >= 0 and cross(o, c, q) >= 0 and cross(c, a, q) >= 0
                for q in live
                if q not in (a, o, c)
            )
            if not inside:
                tris.append((a, o, c))
                live.pop(n)
                break
        else:
            break  # no ear (self-intersecting): fan the rest
    tris += [(live[0], live[n], live[n + 1]) for n in range(1, len(live) - 1)]
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


def mesh_from_primitives(prims: Iterable[Prim]) -> Mesh:
    """One mesh of the 3D primitives (module docstring); other primitives are refused."""
    kinds: dict[str, list[Prim]] = {"seg3": [], "leaf3": [], "sphere": [], "poly3": []}
    for p in prims:
        group = kinds.get(p[0]) if isinstance(p, tuple) and p else None
        if group is None:
            kind = p[0] if isinstance(p, tuple) and p else p
            raise MeshError(f"mesh output is for 3D grammars: cannot mesh a {kind!r} primitive")
        group.append(p)
    b = _Builder()
    if kinds["seg3"]:
        _segments(b, kinds["seg3"])
    if kinds["leaf3"]:
        _leaves(b, kinds["leaf3"])
    if kinds["poly3"]:
        _polygons(b, kinds["poly3"])
    if kinds["sphere"]:
        _spheres(b, kinds["sphere"])
    return b.mesh()
