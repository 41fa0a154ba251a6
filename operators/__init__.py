"""Operators (``sss.*``): thin wrappers that build the job from the settings and call
``sss_addon.blender.render`` (which calls the core)."""

from . import apply_on_render, demo, sequence

#: Registration order (unregistered in reverse).
_MODULES = (sequence, apply_on_render, demo)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()
