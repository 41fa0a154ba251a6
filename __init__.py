"""cvsss: adaptive, temporally stable screen-space subsurface scattering.

Extension entry point: only registration lives here; everything else is in
``sss_addon`` (Blender glue), ``operators`` and ``core`` (pure NumPy).
Importing this package does not import bpy.
"""


def register():
    # Imported here: importing cvsss (as core's users and the background compile do)
    # must not import the Blender glue.
    from . import operators
    from .sss_addon import registration

    registration.register()
    operators.register()


def unregister():
    from . import operators
    from .sss_addon import registration

    operators.unregister()
    registration.unregister()
