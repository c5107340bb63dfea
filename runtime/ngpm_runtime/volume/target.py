"""A 3D target: an occupancy grid in world coordinates and the turtle's start."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class VolumeTarget:
    """occupancy (R, R, R) bool indexed [ix, iy, iz] along world x, y (up), z; voxel (ix, iy,
    iz) spans lo + (ix, iy, iz) * voxel to lo + (ix + 1, iy + 1, iz + 1) * voxel."""

    occupancy: np.ndarray
    lo: np.ndarray
    voxel: float
    start: np.ndarray
    name: str
