"""Files into and out of Blender: splat import/export, COLMAP scenes, splat sequences."""
