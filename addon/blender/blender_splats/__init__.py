"""Blender 5.3's own Gaussian splats (point clouds of type 'GAUSSIAN_SPLAT') in the add-on:
reading and writing them (`data`), which renderer draws them (`ownership`), converting them to
and from the add-on's splat objects (`convert`). In Blender before 5.3 every entry point says
the feature is absent; nothing here crashes there."""
