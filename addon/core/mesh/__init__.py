"""Splats to meshes: the surface (TSDF, surface nets) and its texture."""
