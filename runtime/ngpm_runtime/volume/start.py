"""Where the turtle starts in a 3D target: automatically, or from a sidecar file.

Automatic (as 2D's `auto_start`, which starts at the lowest end of the shape's skeleton
and walks down to the shape's edge): the bottom of the largest connected part (voxels
joined through faces, edges or corners), under the voxel of its lowest layer nearest to the
part's centre seen from above (ties: smallest x, then z). The point is the middle of that voxel's
bottom face, so growth starts at the shape's lowest edge.

Sidecar: `<mesh stem>.txt` beside a mesh, one line `x y z`, each in [0, 1] across the
mesh's bounding box with y up (0 0 0 its lowest-left-back corner; `0.5 0 0.5` the middle of
its floor). 2D's sidecar holds two lines, `x y` and `dx dy`; a 3D start has no direction
(the grammar's start heading is used), so the 3D sidecar is the first line with z added. A
picture that is extruded or revolved keeps its own 2D sidecar (its start lies in the
picture's plane).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ngpm_runtime.files import atomic_write
from ngpm_runtime.volume.target import VolumeError


def label_largest(occupancy: np.ndarray) -> np.ndarray:
    """(R, R, R) bool: the largest part of the filled voxels, 26-connected (through faces,
    edges or corners, as 2D parts are 8-connected; ties: the part holding the voxel that
    comes first in [ix, iy, iz] order)."""
    occ = np.asarray(occupancy, dtype=bool)
    size = occ.size
    lab = np.where(occ.ravel(), np.arange(size), size).reshape(occ.shape)
    while True:
        low = lab
        for axis in range(3):  # the minimum over the 3 x 3 x 3 cube, one axis at a time
            pad = np.pad(
                low, [(1, 1) if a == axis else (0, 0) for a in range(3)], constant_values=size
            )
            side = int(low.shape[axis])
            low = np.minimum(
                np.minimum(pad.take(range(side), axis), pad.take(range(1, side + 1), axis)),
                pad.take(range(2, side + 2), axis),
            )
        low = np.where(occ, low, size)
        flat = np.append(low.ravel(), size)
        low = np.where(occ, flat[low], size)  # jump to the label's own label
        if np.array_equal(low, lab):
            break
        lab = low
    counts = np.bincount(lab.ravel(), minlength=size + 1)[:size]
    if not counts.any():
        raise VolumeError("the target holds no filled voxel")
    out: np.ndarray = lab == int(np.argmax(counts))
    return out


def auto_start(occupancy: np.ndarray) -> np.ndarray:
    """(3,) the automatic start in grid units (voxel (i, j, k) spans [i, i + 1) x ...)."""
    part = label_largest(occupancy)
    cells = np.argwhere(part)
    centre = cells[:, [0, 2]].mean(axis=0) + 0.5
    low = int(cells[:, 1].min())
    floor = cells[cells[:, 1] == low]
    dist = np.hypot(floor[:, 0] + 0.5 - centre[0], floor[:, 2] + 0.5 - centre[1])
    best = floor[np.lexsort((floor[:, 2], floor[:, 0], np.round(dist, 9)))[0]]
    return np.array([best[0] + 0.5, float(low), best[2] + 0.5])


def sidecar3d_path(path: str | os.PathLike[str]) -> Path:
    """The sidecar of a mesh: `<stem>.txt` beside it."""
    return Path(path).with_suffix(".txt")


def read_sidecar3d(path: str | os.PathLike[str]) -> np.ndarray:
    """(3,) the start of a 3D sidecar, `x y z` in [0, 1] (commas allowed)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        reason = getattr(err, "strerror", None) or type(err).__name__
        raise VolumeError(f"cannot read sidecar {path}: {reason}") from None
    lines = [ln.replace(",", " ").split() for ln in text.splitlines() if ln.strip()]
    if len(lines) != 1 or len(lines[0]) != 3:
        raise VolumeError(
            f"bad sidecar {path}: expected one line 'x y z' (each 0 to 1 across the "
            "mesh's bounding box, y up)"
        )
    try:
        values = [float(v) for v in lines[0]]
    except ValueError:
        raise VolumeError(f"bad sidecar {path}: not numbers: {text.strip()[:80]!r}") from None
    if not all(math.isfinite(v) and -1e-6 <= v <= 1 + 1e-6 for v in values):
        raise VolumeError(f"bad sidecar {path}: each of x y z must be from 0 to 1")
    out: np.ndarray = np.clip(np.array(values), 0.0, 1.0)
    return out


def write_sidecar3d(path: str | os.PathLike[str], start: np.ndarray) -> Path:
    """Write a 3D sidecar atomically."""
    x, y, z = (float(v) for v in np.asarray(start, dtype=np.float64).reshape(3))
    if not all(0.0 <= v <= 1.0 for v in (x, y, z)):
        raise VolumeError(f"sidecar {path}: each of x y z must be from 0 to 1")
    return atomic_write(path, f"{x:.6f} {y:.6f} {z:.6f}\n")
