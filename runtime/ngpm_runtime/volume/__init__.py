"""3D targets and growth into them (docs/3d.md): `target.py` (`VolumeTarget`),
`voxelize.py` (meshes, extruded and revolved pictures -> occupancy), `start.py` (start
points), `load.py` (`load_volume_target`); `raster.py` (the voxel canvas), `likelihood.py`
(equation 1 on voxels), `features.py` (3D guide features), `kernels.py` (their numba
kernels), `run.py` (what SMC picks for a 3D grammar)."""
