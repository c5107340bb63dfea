"""Mesh files (geometry/mesh_files.py) read back by independent readers: trimesh for .glb,
.obj and .ply, pygltflib for the glTF structure and materials."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from ngpm_runtime.geometry.mesh import PALETTE, MeshError, mesh_from_primitives

trimesh = pytest.importorskip("trimesh")
pygltflib = pytest.importorskip("pygltflib")

PRIMS = [
    ("seg3", 0, 0, 0, 0, 1, 0, 0.2, 0),
    ("seg3", 0, 1, 0, 0.2, 2, 0.1, 0.15, 0),
    ("seg3", 0.2, 2, 0.1, 0.3, 3, 0.0, 0.1, 2),
    ("leaf3", 0.2, 2, 0.1, 1, 0, 0, 0, 0, 1, 0.8, 0.3, 0),
    ("sphere", 0.3, 3, 0, 0.2, 0),
    ("poly3", ((-1, 0, -1), (-0.5, 0, -1), (-0.5, 0.5, -1)), 4),
]


@pytest.fixture(scope="module")
def mesh():
    return mesh_from_primitives(PRIMS)


def used(mesh) -> list[int]:
    return sorted(set(mesh.face_material.tolist()))


def total(scene) -> tuple[int, int]:
    geoms = list(scene.geometry.values())
    return sum(len(g.vertices) for g in geoms), sum(len(g.faces) for g in geoms)


def test_glb_reads_back_in_trimesh_and_pygltflib(mesh, tmp_path: Path) -> None:
    path = mesh.save(tmp_path / "plant.glb")
    data = path.read_bytes()
    magic, version, length = struct.unpack("<4sII", data[:12])
    assert (magic, version, length) == (b"glTF", 2, len(data))
    scene = trimesh.load(path, process=False)
    assert total(scene) == (len(mesh.vertices), len(mesh.faces))
    assert np.allclose(scene.bounds, mesh.bounds, atol=1e-6)  # Y up, same units
    gltf = pygltflib.GLTF2().load(str(path))
    assert gltf.asset.version == "2.0"
    prims = gltf.meshes[0].primitives
    assert len(prims) == len(gltf.materials) == len(used(mesh))
    names = [m.name for m in gltf.materials]
    assert names == [PALETTE[m].name for m in used(mesh)]
    assert sum(gltf.accessors[p.indices].count for p in prims) == 3 * len(mesh.faces)
    assert sum(gltf.accessors[p.attributes.POSITION].count for p in prims) == len(mesh.vertices)
    bark = gltf.materials[names.index("bark")]
    r, g, b, a = bark.pbrMetallicRoughness.baseColorFactor
    assert bark.doubleSided and a == 1.0
    expect = [((c / 255 + 0.055) / 1.055) ** 2.4 for c in PALETTE[0].rgb]  # sRGB -> linear
    assert np.allclose([r, g, b], expect, atol=1e-5)


def test_glb_materials_keep_their_faces(mesh, tmp_path: Path) -> None:
    scene = trimesh.load(mesh.save(tmp_path / "plant.glb"), process=False)
    found = {g.visual.material.name: len(g.faces) for g in scene.geometry.values()}
    assert found == {PALETTE[m].name: int((mesh.face_material == m).sum()) for m in used(mesh)}


def test_obj_and_mtl_read_back(mesh, tmp_path: Path) -> None:
    path = mesh.save(tmp_path / "plant.obj")
    assert (tmp_path / "plant.mtl").is_file()
    scene = trimesh.load(path, process=False)
    assert total(scene) == (len(mesh.vertices), len(mesh.faces))
    assert np.allclose(scene.bounds, mesh.bounds, atol=1e-5)
    for geom in scene.geometry.values():
        name = geom.visual.material.name
        rgb = next(m.rgb for m in PALETTE if m.name == name)
        assert np.allclose(geom.visual.material.diffuse[:3], rgb, atol=1)
    assert sorted(g.visual.material.name for g in scene.geometry.values()) == sorted(
        PALETTE[m].name for m in used(mesh)
    )


def test_ply_reads_back_with_vertex_colours(mesh, tmp_path: Path) -> None:
    path = mesh.save(tmp_path / "plant.ply")
    tm = trimesh.load(path, process=False)
    assert len(tm.vertices) == len(mesh.vertices) and len(tm.faces) == len(mesh.faces)
    assert np.array_equal(tm.faces, mesh.faces)
    assert np.allclose(tm.vertices, mesh.vertices, atol=1e-6)
    rgb = np.array([m.rgb for m in PALETTE])[mesh.vertex_material()]
    assert np.array_equal(tm.visual.vertex_colors[:, :3], rgb)


def test_empty_mesh_files(tmp_path: Path) -> None:
    empty = mesh_from_primitives([])
    glb = empty.save(tmp_path / "e.glb").read_bytes()
    text = json.loads(glb[20 : 20 + struct.unpack("<I", glb[12:16])[0]])
    assert "meshes" not in text and text["scenes"] == [{"nodes": [0]}]
    assert pygltflib.GLTF2().load(str(tmp_path / "e.glb")).asset.version == "2.0"
    empty.save(tmp_path / "e.ply")
    assert b"element vertex 0" in (tmp_path / "e.ply").read_bytes()


def test_unknown_suffix_and_unwritable_path_are_one_line_errors(mesh, tmp_path: Path) -> None:
    with pytest.raises(MeshError, match=r"unknown mesh format '\.stl'"):
        mesh.save(tmp_path / "plant.stl")
    (tmp_path / "file").write_text("x")
    with pytest.raises(MeshError, match="cannot write"):
        mesh.save(tmp_path / "file" / "plant.glb")
