"""Images on disk: OpenImageIO files and Blender's multilayer OpenEXR."""
