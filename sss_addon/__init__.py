"""Blender glue: settings, panels, pass rendering, image datablocks and the CLI.

Importing this package does not import bpy (the ``cvsss`` command imports
``sss_addon.cli`` without Blender); the submodules that need bpy are loaded
by :func:`register`.
"""


def _modules():
    from .. import operators
    from .blender import native, panels, properties

    # Registration order: properties before the render handlers, operators and panels
    # that use them.
    return (properties, native, operators, panels)


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
