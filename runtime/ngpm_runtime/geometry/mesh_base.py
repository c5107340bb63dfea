"""The mesh's data, apart from how it is built (geometry/mesh.py) so that the writers
(geometry/mesh_files.py) and the renderer (image/render3d.py) need not import the builder."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ngpm_runtime.errors import NgpmError


class MeshError(NgpmError):
    """Primitives that make no mesh, or a mesh file that cannot be written."""


@dataclass(frozen=True)
class Material:
    name: str
    rgb: tuple[int, int, int]  # sRGB, 0-255


PALETTE: tuple[Material, ...] = (
    Material("bark", (101, 67, 33)),
    Material("leaf", (74, 140, 52)),
    Material("dark_bark", (64, 42, 24)),
    Material("pale_wood", (156, 118, 78)),
    Material("young_leaf", (140, 190, 64)),
    Material("dark_leaf", (34, 90, 30)),
    Material("autumn", (216, 176, 52)),
    Material("blossom", (236, 138, 178)),
)


@dataclass(frozen=True)
class MeshData:
    """Triangles with one material per face. `vertices` (V, 3) float64, `faces` (F, 3)
    int64 indices, counter-clockwise seen from outside; `face_material` (F,) indices into
    `materials`. A vertex belongs to faces of one material only."""

    vertices: np.ndarray
    faces: np.ndarray
    face_material: np.ndarray
    materials: tuple[Material, ...] = PALETTE

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3): the lowest and highest corner (zeros for an empty mesh)."""
        if len(self.vertices) == 0:
            return np.zeros((2, 3))
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    def vertex_material(self) -> np.ndarray:
        """(V,) the material of each vertex (0 for a vertex no face uses)."""
        out = np.zeros(len(self.vertices), dtype=np.int64)
        out[self.faces.ravel()] = np.repeat(self.face_material, 3)
        return out
