"""Blender glue: settings, panels, pass rendering, image datablocks and the CLI.

Importing this package does not import bpy (the ``cvsss`` command imports
``sss_addon.cli`` without Blender); the submodules that need bpy are loaded
by :func:`register`.
"""


def _modules():
    from .. import operators
    from .blender import apply_on_render, panels, properties

    # Registration order: properties before the render handlers, operators and panels
    # that use them.
    return (properties, apply_on_render, operators, panels)


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


def _compile_on_load(background: bool) -> bool:
    """In Blender's UI (installed, updated or Blender opened) start compiling every numba
    kernel in a process of their own, so that it happens while the user works instead
    of at the first render (``precompile.start_background``); whether it started.
    ``background``: ``bpy.app.background`` (a render job starts its own)."""
    if background:
        return False
    from ..core.methods import METHODS
    from . import precompile

    return precompile.start_background("auto", tuple(METHODS))


def register():
    import bpy

    _console_log(True)
    for module in _modules():
        module.register()
    _compile_on_load(bpy.app.background)


def unregister():
    from . import precompile

    precompile.stop_background()
    for module in reversed(_modules()):
        module.unregister()
    _console_log(False)
