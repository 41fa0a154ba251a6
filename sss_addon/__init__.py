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


def _console_log(on: bool) -> None:
    """Show the core's log lines (e.g. which sampling backend runs) on Blender's console."""
    import logging

    logger = logging.getLogger("cvsss")
    mine = [h for h in logger.handlers if getattr(h, "cvsss_console", False)]
    if on and not mine:
        handler = logging.StreamHandler()
        handler.cvsss_console = True
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
    elif not on:
        for handler in mine:
            logger.removeHandler(handler)


def register():
    import bpy

    from ..core.methods import METHODS
    from . import precompile

    _console_log(True)
    for module in _modules():
        module.register()
    if not bpy.app.background:
        # Installed, updated or Blender opened: the numba kernels compile in a process
        # of their own while the user works, instead of at the first render.
        precompile.start_background("auto", tuple(METHODS))


def unregister():
    from . import precompile

    precompile.stop_background()
    for module in reversed(_modules()):
        module.unregister()
    _console_log(False)
