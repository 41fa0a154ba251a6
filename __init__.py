"""cvsss: adaptive, temporally stable screen-space subsurface scattering.

Extension entry point: only registration lives here; everything else is in
``sss_addon`` (Blender glue), ``operators`` and ``core`` (pure NumPy).
Importing this package does not import bpy.
"""


def register():
    from .sss_addon import register as _register

    _register()


def unregister():
    from .sss_addon import unregister as _unregister

    _unregister()
