"""3D targets: occupancy grids of voxels that a 3D grammar grows into (docs/3d.md,
"3D targets"): `target.py` (`VolumeTarget`), `voxelize.py` (meshes, extruded and revolved
pictures -> occupancy), `start.py` (start points), `load.py` (`load_volume_target`)."""
