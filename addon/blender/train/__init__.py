"""Training in Blender: the operator, the sidebar panel, Bake to Splats."""
