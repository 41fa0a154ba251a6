"""Operators (``sss.*``): thin wrappers that build the job from the settings and call
``sss_addon.render`` (which calls the core)."""


def _modules():
    from . import apply_on_render, demo, sequence

    return (sequence, apply_on_render, demo)


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
