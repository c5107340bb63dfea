"""Mesh files written with numpy alone: binary glTF (.glb), Wavefront .obj + .mtl, and
binary .ply with vertex colours. Coordinates are the turtle's, Y up, in metres.

No mesh library: these formats are short to write, and trimesh (4.7 MB, about a second to
import) or pygltflib (2 MB with its dependencies) would triple the runtime's install for
what these hundred lines do. The tests read every file back with trimesh and pygltflib.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ngpm_runtime.files import atomic_write
from ngpm_runtime.geometry.mesh_base import MeshData, MeshError

MESH_SUFFIXES = (".glb", ".obj", ".ply")
PICTURE_SUFFIXES = (".png", ".gif")


def _linear(rgb: tuple[int, int, int]) -> list[float]:
    """sRGB 0-255 -> linear 0-1 (glTF's baseColorFactor is linear)."""
    c = np.asarray(rgb, dtype=np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return [round(float(x), 6) for x in lin]


Group = tuple[int, int, int, int, int]  # material, first vertex, vertices, first face, faces


def by_material(mesh: MeshData) -> tuple[np.ndarray, np.ndarray, list[Group]]:
    """Vertices and faces reordered so each material's are contiguous, faces indexing
    into their material's vertex range; with a `Group` per material used."""
    vmat = mesh.vertex_material()
    vorder = np.argsort(vmat, kind="stable")
    new_index = np.empty_like(vorder)
    new_index[vorder] = np.arange(len(vorder))
    forder = np.argsort(mesh.face_material, kind="stable")
    faces = new_index[mesh.faces[forder]]
    fmat = mesh.face_material[forder]
    vcount = np.bincount(vmat, minlength=len(mesh.materials))
    fcount = np.bincount(fmat, minlength=len(mesh.materials))
    vstart = np.concatenate([[0], np.cumsum(vcount)[:-1]])
    fstart = np.concatenate([[0], np.cumsum(fcount)[:-1]])
    groups = [
        (m, int(vstart[m]), int(vcount[m]), int(fstart[m]), int(fcount[m]))
        for m in range(len(mesh.materials))
        if fcount[m]
    ]
    faces = faces - np.repeat(vstart[[g[0] for g in groups]], [g[4] for g in groups])[:, None]
    return mesh.vertices[vorder], faces, groups


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def glb_bytes(mesh: MeshData) -> bytes:
    """Binary glTF 2.0: one mesh, one primitive per material (positions and uint32
    indices), metallic-roughness materials (double-sided: leaves are thin)."""
    verts, faces, groups = by_material(mesh)
    pos = verts.astype("<f4")
    idx = faces.astype("<u4")
    pos_bytes, idx_bytes = pos.tobytes(), idx.tobytes()
    accessors: list[dict[str, Any]] = []
    primitives = []
    materials = []
    for k, (m, v0, vn, f0, fn) in enumerate(groups):
        block = pos[v0 : v0 + vn]
        accessors.append(
            {
                "bufferView": 0,
                "byteOffset": v0 * 12,
                "componentType": 5126,
                "count": vn,
                "type": "VEC3",
                "min": [float(x) for x in block.min(axis=0)],
                "max": [float(x) for x in block.max(axis=0)],
            }
        )
        accessors.append(
            {
                "bufferView": 1,
                "byteOffset": f0 * 12,
                "componentType": 5125,
                "count": fn * 3,
                "type": "SCALAR",
            }
        )
        primitives.append(
            {"attributes": {"POSITION": 2 * k}, "indices": 2 * k + 1, "material": k, "mode": 4}
        )
        mat = mesh.materials[m]
        materials.append(
            {
                "name": mat.name,
                "doubleSided": True,
                "pbrMetallicRoughness": {
                    "baseColorFactor": [*_linear(mat.rgb), 1.0],
                    "metallicFactor": 0.0,
                    "roughnessFactor": 0.9,
                },
            }
        )
    gltf: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "ngpm"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "plant"}],
        "meshes": [{"name": "plant", "primitives": primitives}],
        "materials": materials,
        "accessors": accessors,
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": len(pos_bytes), "target": 34962},
            {
                "buffer": 0,
                "byteOffset": len(pos_bytes),
                "byteLength": len(idx_bytes),
                "target": 34963,
            },
        ],
        "buffers": [{"byteLength": len(pos_bytes) + len(idx_bytes)}],
    }
    if not groups:  # glTF allows no mesh without primitives
        for key in ("meshes", "accessors", "bufferViews", "buffers", "materials"):
            del gltf[key]
        del gltf["nodes"][0]["mesh"]
    text = _pad(json.dumps(gltf, separators=(",", ":")).encode("utf-8"), b" ")
    binary = _pad(pos_bytes + idx_bytes, b"\0")
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
    if groups:
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def obj_text(mesh: MeshData, mtl_name: str) -> tuple[str, str]:
    """(.obj text, .mtl text): faces grouped by `usemtl`, 1-based indices."""
    verts, faces, groups = by_material(mesh)
    out = [
        f"# ngpm plant: {len(verts)} vertices, {len(faces)} triangles, Y up, metres\n",
        f"mtllib {mtl_name}\n",
    ]
    out.append(("v %.6g %.6g %.6g\n" * len(verts)) % tuple(verts.ravel()))
    mtl = ["# ngpm materials\n"]
    for m, v0, _, f0, fn in groups:
        mat = mesh.materials[m]
        out.append(f"o {mat.name}\nusemtl {mat.name}\n")
        block = faces[f0 : f0 + fn] + v0 + 1
        out.append(("f %d %d %d\n" * fn) % tuple(block.ravel()))
        r, g, b = (c / 255 for c in mat.rgb)
        mtl.append(
            f"newmtl {mat.name}\nKd {r:.4f} {g:.4f} {b:.4f}\nKa 0 0 0\nKs 0 0 0\nd 1\nillum 1\n"
        )
    return "".join(out), "".join(mtl)


def ply_bytes(mesh: MeshData) -> bytes:
    """Binary little-endian PLY: float xyz and uchar rgb per vertex, int faces."""
    colors = np.array([m.rgb for m in mesh.materials], dtype=np.uint8)
    vdt = np.dtype(
        [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    )
    vert = np.empty(len(mesh.vertices), dtype=vdt)
    for k, name in enumerate("xyz"):
        vert[name] = mesh.vertices[:, k]
    rgb = colors[mesh.vertex_material()]
    for k, name in enumerate(("red", "green", "blue")):
        vert[name] = rgb[:, k]
    fdt = np.dtype([("n", "u1"), ("i", "<i4", (3,))])
    face = np.empty(len(mesh.faces), dtype=fdt)
    face["n"] = 3
    face["i"] = mesh.faces
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment ngpm plant, Y up, metres\n"
        f"element vertex {len(vert)}\nproperty float x\nproperty float y\n"
        "property float z\nproperty uchar red\nproperty uchar green\n"
        f"property uchar blue\nelement face {len(face)}\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
    return header.encode("ascii") + vert.tobytes() + face.tobytes()


def save_mesh(
    mesh: MeshData,
    path: str | Path,
    size: int | None = None,
    view: tuple[float, float] | None = None,
    frames: int | None = None,
) -> Path:
    """Write the mesh by the suffix: .glb, .obj (and a .mtl beside it), .ply, or a
    picture: .png (`size` default 512) or a turntable .gif (`frames` default 24, `size`
    default 256); `view` (azimuth, elevation in degrees) for both (image.render3d)."""
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".glb":
            atomic_write(path, glb_bytes(mesh))
        elif suffix == ".obj":
            mtl = path.with_suffix(".mtl")
            obj, mtl_text = obj_text(mesh, mtl.name)
            atomic_write(mtl, mtl_text)
            atomic_write(path, obj)
        elif suffix == ".ply":
            atomic_write(path, ply_bytes(mesh))
        elif suffix in PICTURE_SUFFIXES:
            from ngpm_runtime.image.render3d import save_picture

            save_picture(mesh, path, size, view, *([] if frames is None else [frames]))
        else:
            raise MeshError(
                f"{path}: unknown mesh format {suffix or '(none)'!r}; use "
                + ", ".join(MESH_SUFFIXES + PICTURE_SUFFIXES)
            )
    except OSError as err:
        raise MeshError(f"{path}: cannot write: {err.strerror or err}") from None
    return path
