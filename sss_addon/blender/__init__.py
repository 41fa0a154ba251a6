"""sss_addon/blender."""
