"""Registering the add-on's render parts in Blender: settings, Apply on Render, panels.

These are what a render needs, in Blender's UI and in a headless ``cvsss render``
(:func:`.blender.standalone.ensure_registered`). The operators stand on this floor's
shoulders (they call the render glue), so the extension's root ``register`` adds them on
top; nothing here imports them.

Importing this module does not import bpy (the tests of the background
compile import it without Blender); the parts that need bpy are loaded by
:func:`register`.
"""

import logging

from ..core.methods import METHODS
from . import precompile


def _modules():
    # Imported here, not at the top: they import bpy, and this module imports without it.
    from .blender import apply_on_render, panels, properties

    # Registration order: properties before the render handlers and panels that use them
    # (a panel names the operators by their idname, so they may come later).
    return (properties, apply_on_render, panels)


def _console_log(on: bool) -> None:
    """Show the core's log lines (e.g. which sampling backend runs) on Blender's console."""
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
    return precompile.start_background("auto", tuple(METHODS))


def register():
    import bpy

    _console_log(True)
    for module in _modules():
        module.register()
    _compile_on_load(bpy.app.background)


def unregister():
    precompile.stop_background()
    for module in reversed(_modules()):
        module.unregister()
    _console_log(False)
