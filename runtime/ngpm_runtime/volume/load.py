"""`load_volume_target`: a mesh, a picture (extruded or revolved) or a saved .npz as a
`VolumeTarget` in a 3D grammar's grid.

Placement (as 2D targets fill the grammar's viewport): the grid is the cube `box_grid`
fits to the grammar's box (Program.box); the shape is scaled, keeping its proportions,
until its bounding box just fits in the grammar's box, centred in x and z, its lowest point
on the box's floor, where plants start. Then each voxel centre is mapped back into the
shape and tested (ray parity for a mesh, 2 x 2 x 2 points for a lattice).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from ngpm_runtime.errors import printable
from ngpm_runtime.geometry.mesh_base import MeshError
from ngpm_runtime.geometry.mesh_read import READ_SUFFIXES, read_mesh
from ngpm_runtime.image.targets import IMAGE_SUFFIXES, load_target, sidecar_path
from ngpm_runtime.program import Program
from ngpm_runtime.volume import voxelize as vox
from ngpm_runtime.volume.start import auto_start, read_sidecar3d, sidecar3d_path
from ngpm_runtime.volume.target import (
    DEFAULT_RESOLUTION,
    Box,
    VolumeError,
    VolumeTarget,
    box_grid,
    check_resolution,
)

UNIT_BOX: Box = (0.0, 1.0, 0.0, 1.0, 0.0, 1.0)  # the frame datasets are stored in
MIN_VOXELS = 8  # fewer filled voxels than this: no shape to grow into
MAX_EXTRUDE = 4.0  # largest --extrude depth, in picture sides


def program_box(program: Program) -> Box:
    """The box of a 3D grammar; VolumeError for a 2D grammar or one without a box."""
    if program.dim != 3 or program.box is None:
        raise VolumeError(
            f"{printable(program.name)} is a 2D grammar: a 3D target needs a 3D grammar "
            "(with a 'viewport: xmin xmax ymin ymax zmin zmax' box)"
        )
    return program.box


def fit(lo: np.ndarray, hi: np.ndarray, box: Sequence[float]) -> tuple[float, np.ndarray]:
    """(scale, offset): world = shape * scale + offset puts the shape's bounding box
    (lo, hi) in the box: as large as fits, centred in x and z, its floor on the box's."""
    ext = np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64)
    b = np.asarray(box, dtype=np.float64).reshape(3, 2)
    room = b[:, 1] - b[:, 0]
    ratios = [room[a] / ext[a] for a in range(3) if ext[a] > 0]
    if not ratios:
        raise VolumeError("the shape has no extent")
    scale = float(min(ratios))
    anchor_shape = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    anchor_world = np.array([b[0].mean(), b[1, 0], b[2].mean()])
    return scale, anchor_world - scale * anchor_shape


def volume_from_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    box: Sequence[float],
    resolution: int = DEFAULT_RESOLUTION,
    name: str = "mesh",
    start: np.ndarray | None = None,
    where: str | None = None,
) -> VolumeTarget:
    """A closed mesh placed in the box's grid; `start` in [0, 1]^3 across the mesh's
    bounding box (None: automatic); `where` names the mesh in errors (default `name`)."""
    r = check_resolution(resolution)
    where = name if where is None else where
    v, f = vox.check_closed(vertices, faces, where)
    used = v[np.unique(f)]
    lo_s, hi_s = used.min(axis=0), used.max(axis=0)
    scale, offset = fit(lo_s, hi_s, box)
    lo, voxel = box_grid(box, r)
    occ = vox.voxelize_mesh(v, f, (lo - offset) / scale, voxel / scale, r, where)
    shape_start = None if start is None else lo_s + np.asarray(start) * (hi_s - lo_s)
    return _finish(occ, lo, voxel, name, shape_start, scale, offset, where)


def volume_from_lattice(
    lattice: np.ndarray,
    box: Sequence[float],
    resolution: int = DEFAULT_RESOLUTION,
    name: str = "volume",
    start: np.ndarray | None = None,
) -> VolumeTarget:
    """A lattice of unit cells (bool [ix, iy, iz], y up) placed in the box's grid;
    `start` in the lattice's units (None: automatic)."""
    r = check_resolution(resolution)
    lat = np.asarray(lattice, dtype=bool)
    cells = np.argwhere(lat)
    if cells.size == 0:
        raise VolumeError(f"{name}: the shape is empty")
    lo_s, hi_s = cells.min(axis=0).astype(np.float64), cells.max(axis=0) + 1.0
    scale, offset = fit(lo_s, hi_s, box)
    lo, voxel = box_grid(box, r)
    occ = vox.sample_lattice(lat, (lo - offset) / scale, voxel / scale, r)
    return _finish(occ, lo, voxel, name, start, scale, offset, name)


def _finish(
    occ: np.ndarray,
    lo: np.ndarray,
    voxel: float,
    name: str,
    shape_start: np.ndarray | None,
    scale: float,
    offset: np.ndarray,
    where: str,
) -> VolumeTarget:
    count = int(occ.sum())
    if count < MIN_VOXELS:
        raise VolumeError(
            f"{where}: only {count} voxel(s) of the {occ.shape[0]}^3 grid are inside the "
            "shape (too thin for this resolution)"
        )
    if shape_start is None:
        start = lo + auto_start(occ) * voxel
    else:
        start = np.asarray(shape_start, dtype=np.float64) * scale + offset
    return VolumeTarget(occ, lo, voxel, start, name)


def place(
    target: VolumeTarget, box: Sequence[float], resolution: int | None = None
) -> VolumeTarget:
    """A target moved into a box's grid (its shape fitted again, as `volume_from_lattice`
    does); the target itself when it is on that grid already."""
    r = target.resolution if resolution is None else check_resolution(resolution)
    lo, voxel = box_grid(box, r)
    if r == target.resolution and np.allclose(lo, target.lo) and math.isclose(voxel, target.voxel):
        return target
    start = (target.start - target.lo) / target.voxel
    return volume_from_lattice(target.occupancy, box, r, target.name, start)


def load_volume_target(
    path: str | os.PathLike[str],
    program: Program,
    *,
    resolution: int = DEFAULT_RESOLUTION,
    extrude: float | None = None,
    revolve: bool = False,
    polarity: str = "auto",
) -> VolumeTarget:
    """A 3D target for a 3D grammar from a mesh (.obj, .stl, .ply, .glb; start from its
    sidecar `<stem>.txt`, else automatic), a saved target (.npz) or a picture made 3D by
    `extrude` (depth in picture sides: 0.25 is a quarter of the picture's side) or
    `revolve` (about the shape's vertical middle; its 2D sidecar's start when it has one,
    else automatic). Every problem is a one-line VolumeError (or TargetError, MeshError)."""
    path = Path(path)
    box = program_box(program)
    r = check_resolution(resolution)
    suffix = path.suffix.lower()
    picture = suffix in IMAGE_SUFFIXES
    if (extrude is not None or revolve) and not picture:
        raise VolumeError(
            f"{path}: --extrude and --revolve make pictures 3D, not {suffix or 'this'} files"
        )
    if suffix in READ_SUFFIXES:
        try:
            vertices, faces = read_mesh(path)
        except MeshError as err:
            raise VolumeError(str(err)) from None
        side = sidecar3d_path(path)
        start = read_sidecar3d(side) if side.is_file() else None
        return volume_from_mesh(vertices, faces, box, r, path.stem, start, f"mesh {path}")
    if suffix == ".npz":
        return place(VolumeTarget.from_npz(path), box, r)
    if picture:
        return _from_picture(path, box, r, extrude, revolve, polarity)
    known = ", ".join((*READ_SUFFIXES, ".npz"))
    raise VolumeError(
        f"{path}: a 3D target is a mesh or a .npz ({known}) or a picture with "
        "--extrude or --revolve"
    )


def _from_picture(
    path: Path, box: Box, r: int, extrude: float | None, revolve: bool, polarity: str
) -> VolumeTarget:
    if extrude is not None and revolve:
        raise VolumeError(f"{path}: choose --extrude or --revolve, not both")
    if extrude is None and not revolve:
        raise VolumeError(
            f"{path} is a picture: make it 3D with --extrude DEPTH (pushed along z) or "
            "--revolve (turned about its vertical middle)"
        )
    if extrude is not None and not (math.isfinite(extrude) and 0 < extrude <= MAX_EXTRUDE):
        raise VolumeError(
            f"--extrude must be a depth above 0 and at most {MAX_EXTRUDE:g} "
            f"(in picture sides), got {extrude}"
        )
    size = max(2 * r, 16)
    target = load_target(path, size=size, polarity=polarity)
    mask = target.mask
    x, y = target.start[0] * size, (1.0 - target.start[1]) * size
    if extrude is not None:
        cells = max(1, int(round(extrude * size)))
        lattice = vox.extrude(mask, cells)
        start = np.array([x, y, cells / 2.0])
    else:
        lattice = vox.revolve(mask)
        c0, c1 = vox.revolve_span(mask)
        start = np.array([x - c0, y, (c1 - c0) / 2.0])
    has_sidecar = sidecar_path(path).is_file()
    made = volume_from_lattice(lattice, box, r, str(path), start if has_sidecar else None)
    return replace(made, name=path.stem)


def load_volume_dataset(
    directory: str | os.PathLike[str], program: Program | None = None, resolution: int | None = None
) -> list[VolumeTarget]:
    """The targets of a 3D dataset directory (its index.json's .npz files, in order),
    placed in the program's grid when one is given."""
    directory = Path(directory)
    index = directory / "index.json"
    try:
        meta = json.loads(index.read_text(encoding="utf-8"))
        files = [directory / str(f) for f in meta["files"]]
    except FileNotFoundError:
        raise VolumeError(f"{directory} holds no 3D dataset (no index.json)") from None
    except (OSError, ValueError, KeyError, TypeError):
        raise VolumeError(f"bad dataset index {index}: expected JSON with 'files'") from None
    if meta.get("complete") is False:
        raise VolumeError(
            f"dataset {directory} is incomplete (interrupted build); run the same build again"
        )
    if any(f.suffix.lower() != ".npz" for f in files):
        raise VolumeError(
            f"{directory} is a set of pictures, not of 3D targets: a 3D grammar grows into "
            "3D target sets (`ngpmc targets build blobs3d -o DIR`, docs/3d.md)"
        )
    targets = [VolumeTarget.from_npz(f) for f in files]
    if program is None:
        return targets
    box = program_box(program)
    return [place(t, box, resolution) for t in targets]
