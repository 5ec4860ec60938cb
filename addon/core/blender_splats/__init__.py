"""Blender 5.3's own Gaussian splats (a point cloud of type 'GAUSSIAN_SPLAT') as plain arrays:
the attribute convention and the conversion to and from `Gaussians`. Never imports bpy."""
