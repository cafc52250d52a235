"""Fusion of settled frames into the map: ``tsdf`` (Open3D's VoxelBlockGrid and the mesh)."""
