"""cvsss: adaptive, temporally stable screen-space subsurface scattering.

Extension entry point: only registration lives here; everything else is in
``sss_addon`` (Blender glue), ``operators`` and ``core`` (pure NumPy).
Importing this package does not import bpy.
"""


def register():
    # Imported here: importing cvsss (as core's users and the background compile do)
    # must not import the Blender glue.
    from .sss_addon.registration import register as _register

    _register()


def unregister():
    from .sss_addon.registration import unregister as _unregister

    _unregister()
