"""Triangle meshes read with numpy alone: Wavefront .obj, .stl (ASCII and binary), .ply
(ASCII, binary little- and big-endian) and binary glTF (.glb). Only the geometry is read:
`read_mesh` returns vertices (V, 3) float64 and triangles (F, 3) int64 (polygons are cut
into fans; glTF nodes' transforms are applied). Every problem is a one-line MeshError that
names the file. The writers are mesh_files.py.
"""

from __future__ import annotations

import json
import os
import re
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ngpm_runtime.geometry.mesh_base import MeshError

READ_SUFFIXES = (".obj", ".stl", ".ply", ".glb")
MAX_BYTES = 1 << 30  # larger files are refused before reading
Mesh = tuple[np.ndarray, np.ndarray]  # vertices (V, 3) float64, triangles (F, 3) int64


def read_mesh(path: str | os.PathLike[str]) -> Mesh:
    """(vertices, triangles) of a mesh file, by its suffix; indices checked."""
    path = Path(path)
    name = f"mesh {path}"
    suffix = path.suffix.lower()
    if suffix not in READ_SUFFIXES:
        raise MeshError(
            f"{name}: unknown mesh format {suffix or '(none)'!r}; use {', '.join(READ_SUFFIXES)}"
        )
    try:
        if path.is_dir():
            raise MeshError(f"{path} is a folder, not a mesh")
        if path.stat().st_size > MAX_BYTES:
            raise MeshError(f"{name}: the file is larger than {MAX_BYTES >> 20} MiB")
        data = path.read_bytes()
    except FileNotFoundError:
        raise MeshError(f"{name} does not exist") from None
    except OSError as err:
        raise MeshError(f"cannot read {name}: {err.strerror or err}") from None
    reader = {".obj": _obj, ".stl": _stl, ".ply": _ply, ".glb": _glb}[suffix]
    try:
        verts, faces = reader(data, name)
    except MeshError:
        raise
    except (ValueError, IndexError, KeyError, TypeError, struct.error, UnicodeDecodeError) as err:
        reason = str(err).splitlines()[0][:120] if str(err) else type(err).__name__
        raise MeshError(f"cannot read {name}: {reason}") from None
    verts = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
        raise MeshError(f"{name}: a face refers to a vertex that does not exist")
    if not np.all(np.isfinite(verts)):
        raise MeshError(f"{name}: a vertex coordinate is not a finite number")
    return verts, faces


def _fan(polys: list[list[int]]) -> np.ndarray:
    """Triangles of polygons (vertex index lists) cut into fans from their first vertex."""
    tris = [(p[0], p[k], p[k + 1]) for p in polys for k in range(1, len(p) - 1)]
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


# --- OBJ ---------------------------------------------------------------------------------


def _obj(data: bytes, name: str) -> Mesh:
    verts: list[list[float]] = []
    polys: list[list[int]] = []
    for num, raw in enumerate(data.decode("utf-8", errors="replace").splitlines(), 1):
        parts = raw.split("#", 1)[0].split()
        if not parts:
            continue
        if parts[0] == "v":
            if len(parts) < 4:
                raise MeshError(f"{name}:{num}: a vertex needs three coordinates")
            verts.append([float(v) for v in parts[1:4]])
        elif parts[0] == "f":
            idx = []
            for tok in parts[1:]:
                i = int(tok.split("/", 1)[0])
                if i == 0:
                    raise MeshError(f"{name}:{num}: vertex index 0 (OBJ counts from 1)")
                idx.append(i - 1 if i > 0 else len(verts) + i)
            if len(idx) < 3:
                raise MeshError(f"{name}:{num}: a face needs three vertices")
            polys.append(idx)
    return np.array(verts, dtype=np.float64).reshape(-1, 3), _fan(polys)


# --- STL ---------------------------------------------------------------------------------

_STL_VERTEX = re.compile(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)")


def _stl(data: bytes, name: str) -> Mesh:
    if len(data) >= 84:
        (count,) = struct.unpack_from("<I", data, 80)
        if 84 + 50 * count == len(data):  # binary (its header may start with "solid" too)
            rec = np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
            tris = np.frombuffer(data, rec, count, 84)["v"].astype(np.float64)
            return tris.reshape(-1, 3), np.arange(3 * count).reshape(-1, 3)
    if not data.lstrip().startswith(b"solid"):
        raise MeshError(f"cannot read {name}: neither ASCII STL nor binary STL")
    found = _STL_VERTEX.findall(data)
    if len(found) % 3:
        raise MeshError(f"cannot read {name}: a facet without three vertices")
    verts = np.array(found, dtype=np.float64).reshape(-1, 3)
    return verts, np.arange(len(verts)).reshape(-1, 3)


# --- PLY ---------------------------------------------------------------------------------

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
# a property: (name, scalar type, None) or (name, index type, count type) for a list
Prop = tuple[str, str, str | None]


def _ply_header(data: bytes, name: str) -> tuple[str, list[tuple[str, int, list[Prop]]], int]:
    """(format, [(element, count, properties)], offset of the body)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise MeshError(f"cannot read {name}: not a PLY file (no 'ply' ... 'end_header')")
    body = data.index(b"\n", end) + 1
    fmt = ""
    elements: list[tuple[str, int, list[Prop]]] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        w = line.split()
        if not w or w[0] in ("comment", "obj_info"):
            continue
        if w[0] == "format":
            fmt = w[1]
        elif w[0] == "element":
            elements.append((w[1], int(w[2]), []))
        elif w[0] == "property" and elements:
            if w[1] == "list":
                elements[-1][2].append((w[4], _ply_type(w[3], name), _ply_type(w[2], name)))
            else:
                elements[-1][2].append((w[2], _ply_type(w[1], name), None))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise MeshError(f"cannot read {name}: PLY format {fmt or '(none)'!r} is unknown")
    return fmt, elements, body


def _ply_type(word: str, name: str) -> str:
    if word not in _PLY_TYPES:
        raise MeshError(f"cannot read {name}: PLY property type {word!r} is unknown")
    return _PLY_TYPES[word]


def _ply(data: bytes, name: str) -> Mesh:
    fmt, elements, offset = _ply_header(data, name)
    reader = _PlyAscii(data[offset:]) if fmt == "ascii" else _PlyBinary(data, offset, fmt)
    verts: np.ndarray | None = None
    faces: np.ndarray | None = None
    for element, count, props in elements:
        if element == "vertex":
            cols = reader.scalars(count, props)
            missing = [c for c in "xyz" if c not in cols]
            if missing:
                raise MeshError(f"cannot read {name}: vertices have no {missing[0]}")
            verts = np.stack([cols[c] for c in "xyz"], axis=1).astype(np.float64)
        elif element == "face":
            faces = reader.faces(count, props, name)
        elif verts is not None and faces is not None:
            break
        else:
            reader.skip(count, props)
    if verts is None or faces is None:
        raise MeshError(f"cannot read {name}: the PLY file has no vertex or no face element")
    return verts, faces


def _face_list(props: list[Prop], name: str) -> int:
    """Position of the face element's list of vertex indices."""
    for k, (pname, _, count_type) in enumerate(props):
        if count_type is not None and pname in ("vertex_indices", "vertex_index"):
            return k
    raise MeshError(f"cannot read {name}: faces have no vertex_indices list")


class _PlyAscii:
    def __init__(self, body: bytes) -> None:
        self.tokens = body.split()
        self.pos = 0

    def _take(self, n: int) -> list[bytes]:
        if self.pos + n > len(self.tokens):
            raise ValueError("the PLY body ends early")
        out = self.tokens[self.pos : self.pos + n]
        self.pos += n
        return out

    def scalars(self, count: int, props: list[Prop]) -> dict[str, np.ndarray]:
        if any(p[2] is not None for p in props):
            self.skip(count, props)
            return {}
        table = np.array(self._take(count * len(props)), dtype=np.float64)
        table = table.reshape(count, len(props))
        return {p[0]: table[:, k] for k, p in enumerate(props)}

    def _rows(self, count: int, props: list[Prop]) -> list[list[list[float]]]:
        rows = []
        for _ in range(count):
            row = []
            for _pname, _t, count_type in props:
                n = int(float(self._take(1)[0])) if count_type is not None else 1
                row.append([float(v) for v in self._take(n)])
            rows.append(row)
        return rows

    def faces(self, count: int, props: list[Prop], name: str) -> np.ndarray:
        k = _face_list(props, name)
        if len(props) == 1 and count:  # one list: try equal lengths at once
            n = int(float(self.tokens[self.pos]))
            if self.pos + count * (n + 1) <= len(self.tokens):
                table = np.array(self.tokens[self.pos : self.pos + count * (n + 1)], np.float64)
                table = table.reshape(count, n + 1)
                if n >= 3 and np.all(table[:, 0] == n):
                    self.pos += count * (n + 1)
                    return _fan_table(table[:, 1:].astype(np.int64))
        return _fan([[int(i) for i in row[k]] for row in self._rows(count, props)])

    def skip(self, count: int, props: list[Prop]) -> None:
        self._rows(count, props)


class _PlyBinary:
    def __init__(self, data: bytes, offset: int, fmt: str) -> None:
        self.data = data
        self.pos = offset
        self.order = "<" if fmt == "binary_little_endian" else ">"

    def _dt(self, t: str) -> np.dtype[Any]:
        return np.dtype(self.order + t)

    def scalars(self, count: int, props: list[Prop]) -> dict[str, np.ndarray]:
        if any(p[2] is not None for p in props):
            self.skip(count, props)
            return {}
        dt = np.dtype([(f"p{k}", self._dt(p[1])) for k, p in enumerate(props)])
        table = np.frombuffer(self.data, dt, count, self.pos)
        self.pos += count * dt.itemsize
        return {p[0]: table[f"p{k}"] for k, p in enumerate(props)}

    def _rows(self, count: int, props: list[Prop]) -> list[list[np.ndarray]]:
        rows = []
        for _ in range(count):
            row = []
            for _pname, t, count_type in props:
                n = 1
                if count_type is not None:
                    cdt = self._dt(count_type)
                    n = int(np.frombuffer(self.data, cdt, 1, self.pos)[0])
                    self.pos += cdt.itemsize
                dt = self._dt(t)
                row.append(np.frombuffer(self.data, dt, n, self.pos))
                self.pos += n * dt.itemsize
            rows.append(row)
        return rows

    def faces(self, count: int, props: list[Prop], name: str) -> np.ndarray:
        k = _face_list(props, name)
        _pname, t, count_type = props[k]
        if len(props) == 1 and count and count_type is not None:
            cdt, idt = self._dt(count_type), self._dt(t)
            n = int(np.frombuffer(self.data, cdt, 1, self.pos)[0])
            rec = np.dtype([("n", cdt), ("i", idt, (n,))])
            if n >= 3 and self.pos + count * rec.itemsize <= len(self.data):
                table = np.frombuffer(self.data, rec, count, self.pos)
                if np.all(table["n"] == n):
                    self.pos += count * rec.itemsize
                    return _fan_table(table["i"].astype(np.int64))
        return _fan([[int(i) for i in row[k]] for row in self._rows(count, props)])

    def skip(self, count: int, props: list[Prop]) -> None:
        if all(p[2] is None for p in props):
            self.pos += count * sum(self._dt(p[1]).itemsize for p in props)
        else:
            self._rows(count, props)


def _fan_table(polys: np.ndarray) -> np.ndarray:
    """Fans of polygons of equal length (P, n) -> (P * (n - 2), 3)."""
    n = polys.shape[1]
    tris = [np.stack([polys[:, 0], polys[:, k], polys[:, k + 1]], axis=1) for k in range(1, n - 1)]
    return np.stack(tris, axis=1).reshape(-1, 3)


# --- glTF (.glb) -------------------------------------------------------------------------

_COMPONENTS = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def _glb(data: bytes, name: str) -> Mesh:
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF" or version != 2:
        raise MeshError(f"cannot read {name}: not a binary glTF 2.0 file")
    pos, gltf, binary = 12, None, b""
    while pos + 8 <= min(length, len(data)):
        size, kind = struct.unpack_from("<II", data, pos)
        chunk = data[pos + 8 : pos + 8 + size]
        if kind == 0x4E4F534A:
            gltf = json.loads(chunk.decode("utf-8"))
        elif kind == 0x004E4942 and not binary:
            binary = chunk
        pos += 8 + size
    if not isinstance(gltf, dict):
        raise MeshError(f"cannot read {name}: no JSON chunk")
    for ext in gltf.get("extensionsRequired", []):
        raise MeshError(f"cannot read {name}: glTF extension {ext} is not supported")
    verts: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    count = 0
    for mesh_index, matrix in _glb_instances(gltf):
        for prim in gltf["meshes"][mesh_index].get("primitives", []):
            if prim.get("mode", 4) != 4:
                raise MeshError(
                    f"cannot read {name}: primitive mode {prim['mode']} (not triangles)"
                )
            pos_arr = _accessor(gltf, binary, prim["attributes"]["POSITION"], name)
            if pos_arr.shape[1] != 3:
                raise MeshError(f"cannot read {name}: POSITION is not VEC3")
            p = pos_arr.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]
            if "indices" in prim:
                idx = _accessor(gltf, binary, prim["indices"], name).astype(np.int64).ravel()
            else:
                idx = np.arange(len(p))
            if len(idx) % 3:
                raise MeshError(f"cannot read {name}: indices are not whole triangles")
            verts.append(p)
            faces.append(idx.reshape(-1, 3) + count)
            count += len(p)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return np.concatenate(verts), np.concatenate(faces)


def _glb_instances(gltf: dict[str, Any]) -> list[tuple[int, np.ndarray]]:
    """(mesh index, world matrix) of every node with a mesh in the scene (or of the
    meshes themselves when there are no nodes)."""
    nodes = gltf.get("nodes", [])
    if not nodes:
        return [(k, np.eye(4)) for k in range(len(gltf.get("meshes", [])))]
    scenes = gltf.get("scenes", [])
    if scenes:
        roots = list(scenes[gltf.get("scene", 0)].get("nodes", []))
    else:
        children = {c for n in nodes for c in n.get("children", [])}
        roots = [k for k in range(len(nodes)) if k not in children]
    out: list[tuple[int, np.ndarray]] = []
    stack = [(k, np.eye(4), 0) for k in roots]
    while stack:
        k, parent, depth = stack.pop()
        if depth > 64:
            raise ValueError("the node tree is deeper than 64 (a cycle?)")
        node = nodes[k]
        world = parent @ _node_matrix(node)
        if "mesh" in node:
            out.append((int(node["mesh"]), world))
        stack.extend((int(c), world, depth + 1) for c in node.get("children", []))
    return out


def _node_matrix(node: dict[str, Any]) -> np.ndarray:
    if "matrix" in node:
        given: np.ndarray = np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
        return given  # glTF's matrices are column-major
    t = np.array(node.get("translation", [0, 0, 0]), dtype=np.float64)
    x, y, z, w = (float(v) for v in node.get("rotation", [0, 0, 0, 1]))
    s = np.array(node.get("scale", [1, 1, 1]), dtype=np.float64)
    rot = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = rot * s
    m[:3, 3] = t
    return m


def _accessor(gltf: dict[str, Any], binary: bytes, index: int, name: str) -> np.ndarray:
    """(count, width) array of an accessor of the BIN chunk."""
    acc = gltf["accessors"][index]
    if "sparse" in acc or "bufferView" not in acc:
        raise MeshError(f"cannot read {name}: sparse or empty accessors are not supported")
    view = gltf["bufferViews"][acc["bufferView"]]
    if "uri" in gltf["buffers"][view["buffer"]]:
        raise MeshError(f"cannot read {name}: external buffers are not supported (.glb only)")
    dt = np.dtype("<" + _COMPONENTS[acc["componentType"]])
    width, count = _WIDTHS[acc["type"]], int(acc["count"])
    elem = dt.itemsize * width
    stride = int(view.get("byteStride", elem))
    start = int(view.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
    end = start + stride * (count - 1) + elem if count else start
    if end > len(binary) or stride < elem:
        raise MeshError(f"cannot read {name}: an accessor runs past its buffer")
    raw = np.frombuffer(binary, np.uint8, end - start, start)
    raw = np.concatenate([raw, np.zeros(stride * count - len(raw), np.uint8)])
    table = raw.reshape(count, stride)[:, :elem].copy()
    out: np.ndarray = table.view(dt).reshape(count, width)
    return out
