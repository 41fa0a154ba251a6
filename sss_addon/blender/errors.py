"""The error the Blender glue raises for a problem the user can fix."""


class RenderError(ValueError):
    """A problem with the scene or the settings that the user can fix."""
