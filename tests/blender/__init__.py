"""bpy lane: the add-on in real headless Blender."""
