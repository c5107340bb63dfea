"""`VolumeTarget`: an occupancy grid of R x R x R voxels placed in world coordinates.

`occupancy[ix, iy, iz]` is True for a voxel of the shape; voxel (ix, iy, iz) covers world
`lo + (ix, iy, iz) * voxel` to `lo + (ix + 1, iy + 1, iz + 1) * voxel` (x, y up, z, as the 3D
turtle's). `start` is the world point where the turtle starts. The grid of a grammar is the
cube `box_grid` fits to its box (Program.box); `load.py` places shapes into it.
"""

from __future__ import annotations

import io
import math
import os
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ngpm_runtime.errors import TargetError
from ngpm_runtime.files import atomic_write
from ngpm_runtime.geometry.mesh_base import Material, MeshData

DEFAULT_RESOLUTION = 32
MIN_RESOLUTION, MAX_RESOLUTION = 4, 256
NPZ_VERSION = 1
Box = tuple[float, float, float, float, float, float]  # xmin xmax ymin ymax zmin zmax


class VolumeError(TargetError):
    """A 3D target (mesh, picture, .npz file) that cannot be used."""


@dataclass(frozen=True, eq=False)
class VolumeTarget:
    """An occupancy grid (R, R, R) bool indexed [ix, iy, iz], its min corner `lo` (3,), the
    edge length `voxel` of a voxel and the world `start` (3,) of the turtle."""

    occupancy: np.ndarray
    lo: np.ndarray
    voxel: float
    start: np.ndarray
    name: str = "target"

    def __post_init__(self) -> None:
        occ = np.asarray(self.occupancy)
        shape = occ.shape
        if occ.ndim != 3 or len(set(shape)) != 1 or shape[0] < 1:
            raise VolumeError(f"target {self.name}: occupancy must be (R, R, R), got {shape}")
        object.__setattr__(self, "occupancy", occ.astype(bool, copy=False))
        object.__setattr__(self, "lo", _point(self.lo, f"target {self.name}: lo"))
        object.__setattr__(self, "start", _point(self.start, f"target {self.name}: start"))
        voxel = float(self.voxel)
        if not (math.isfinite(voxel) and voxel > 0):
            raise VolumeError(f"target {self.name}: voxel must be a positive number, got {voxel}")
        object.__setattr__(self, "voxel", voxel)

    @property
    def resolution(self) -> int:
        """R, the voxels along each axis."""
        return int(self.occupancy.shape[0])

    @property
    def hi(self) -> np.ndarray:
        """(3,) the grid's max corner."""
        hi: np.ndarray = self.lo + self.resolution * self.voxel
        return hi

    def world_to_index(self, points: np.ndarray | Sequence[float]) -> np.ndarray:
        """(..., 3) int64 indices of the voxels holding world points (may lie outside
        0..R-1: check with `inside`)."""
        p = np.asarray(points, dtype=np.float64)
        idx: np.ndarray = np.floor((p - self.lo) / self.voxel).astype(np.int64)
        return idx

    def index_to_world(self, index: np.ndarray | Sequence[int]) -> np.ndarray:
        """(..., 3) world centres of voxels."""
        i = np.asarray(index, dtype=np.float64)
        out: np.ndarray = self.lo + (i + 0.5) * self.voxel
        return out

    def inside(self, index: np.ndarray) -> np.ndarray:
        """(...,) bool: which indices (..., 3) lie in the grid."""
        idx = np.asarray(index)
        ok: np.ndarray = np.all((idx >= 0) & (idx < self.resolution), axis=-1)
        return ok

    def boundary(self) -> np.ndarray:
        """(R, R, R) bool: filled voxels with an empty 6-neighbour (outside the grid is
        empty)."""
        return boundary(self.occupancy)

    def filled_fraction(self) -> float:
        return float(self.occupancy.mean())

    def mesh(self) -> MeshData:
        """The voxels' outer faces as a mesh (world coordinates), for pictures."""
        return voxel_mesh(self.occupancy, self.lo, self.voxel)

    def to_npz(self, path: str | os.PathLike[str]) -> Path:
        """Write the target as a compressed .npz, atomically."""
        buf = io.BytesIO()
        np.savez_compressed(
            buf,
            version=np.int64(NPZ_VERSION),
            occupancy=np.packbits(self.occupancy.ravel()),
            resolution=np.int64(self.resolution),
            lo=self.lo,
            voxel=np.float64(self.voxel),
            start=self.start,
            name=np.str_(self.name),
        )
        return atomic_write(path, buf.getvalue())

    @classmethod
    def from_npz(cls, path: str | os.PathLike[str]) -> VolumeTarget:
        """Read a target `to_npz` wrote; a VolumeError naming the file otherwise."""
        where = f"3D target {path}"
        try:
            with np.load(path, allow_pickle=False) as data:
                if int(data["version"]) != NPZ_VERSION:
                    raise VolumeError(f"{where}: file version {int(data['version'])} is unknown")
                r = int(data["resolution"])
                if not MIN_RESOLUTION <= r <= MAX_RESOLUTION:
                    raise VolumeError(f"{where}: resolution {r} is out of range")
                bits = np.unpackbits(data["occupancy"])[: r**3]
                if bits.size != r**3:
                    raise VolumeError(f"{where}: occupancy holds too few voxels")
                return cls(
                    bits.reshape(r, r, r).astype(bool),
                    data["lo"],
                    float(data["voxel"]),
                    data["start"],
                    str(data["name"]),
                )
        except FileNotFoundError:
            raise VolumeError(f"{where} does not exist") from None
        except VolumeError:
            raise
        except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile, EOFError) as err:
            reason = str(err).splitlines()[0][:120] if str(err) else type(err).__name__
            raise VolumeError(f"cannot read {where}: {reason}") from None


def _point(value: object, where: str) -> np.ndarray:
    try:
        p = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise VolumeError(f"{where} must be three numbers") from None
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise VolumeError(f"{where} must be three finite numbers")
    return p


def check_resolution(resolution: object) -> int:
    """The grid resolution as an int; VolumeError unless MIN_RESOLUTION..MAX_RESOLUTION."""
    if (
        isinstance(resolution, bool)
        or not isinstance(resolution, (int, np.integer))
        or not MIN_RESOLUTION <= int(resolution) <= MAX_RESOLUTION
    ):
        raise VolumeError(
            f"resolution must be an integer from {MIN_RESOLUTION} to {MAX_RESOLUTION}, "
            f"got {resolution!r}"
        )
    return int(resolution)


def box_grid(
    box: Sequence[float], resolution: int = DEFAULT_RESOLUTION
) -> tuple[np.ndarray, float]:
    """(lo, voxel) of the cube grid of a box: edge the box's largest extent, centred on the
    box in x and z, its floor the box's floor (where plants start), so the box lies in it."""
    x0, x1, y0, y1, z0, z1 = (float(v) for v in box)
    side = max(x1 - x0, y1 - y0, z1 - z0)
    if not (math.isfinite(side) and side > 0):
        raise VolumeError(f"the box {tuple(box)} has no extent")
    lo = np.array([(x0 + x1 - side) / 2, y0, (z0 + z1 - side) / 2])
    return lo, side / resolution


def boundary(occupancy: np.ndarray) -> np.ndarray:
    """Filled voxels with an empty 6-neighbour (outside the grid counts as empty)."""
    occ = np.asarray(occupancy, dtype=bool)
    pad = np.pad(occ, 1)
    interior = occ.copy()
    for axis in range(3):
        for step in (-1, 1):
            interior &= np.roll(pad, step, axis=axis)[1:-1, 1:-1, 1:-1]
    out: np.ndarray = occ & ~interior
    return out


# corners of a voxel's face toward -x, +x, -y, +y, -z, +z (counter-clockwise from outside)
_FACES = {
    (0, -1): ((0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)),
    (0, 1): ((1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)),
    (1, -1): ((0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)),
    (1, 1): ((0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 1, 0)),
    (2, -1): ((0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 0)),
    (2, 1): ((0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)),
}
VOXEL_MATERIAL = (Material("target", (96, 150, 210)),)


def voxel_mesh(occupancy: np.ndarray, lo: np.ndarray, voxel: float) -> MeshData:
    """Two triangles for each face between a filled voxel and an empty one (or the grid's
    outside); faces are not shared between quads (flat shading)."""
    occ = np.asarray(occupancy, dtype=bool)
    pad = np.pad(occ, 1)
    quads = []
    for (axis, step), corners in _FACES.items():
        neighbour = np.roll(pad, -step, axis=axis)[1:-1, 1:-1, 1:-1]
        cells = np.argwhere(occ & ~neighbour)
        quads.append(cells[:, None, :] + np.array(corners)[None])
    allq = np.concatenate(quads).astype(np.float64) if quads else np.zeros((0, 4, 3))
    verts = (np.asarray(lo, dtype=np.float64) + allq * float(voxel)).reshape(-1, 3)
    base = 4 * np.arange(len(allq))[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3)
    return MeshData(verts, faces.astype(np.int64), np.zeros(len(faces), np.int64), VOXEL_MATERIAL)
