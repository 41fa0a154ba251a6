"""Operators (``sss.*``): thin wrappers that build the job from the settings and call
``sss_addon.render`` (which calls the core)."""


def _modules():
    from . import demo, native, sequence

    return (sequence, native, demo)


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
