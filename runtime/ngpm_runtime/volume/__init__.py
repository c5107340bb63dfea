"""3D targets and growth into them: voxel targets, the voxel canvas, likelihood and features."""
