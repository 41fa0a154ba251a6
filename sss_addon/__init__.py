"""Blender glue, the command line and the farm front-end around the core.

:mod:`.registration` registers the add-on's parts in Blender; importing this
package imports nothing (the ``cvsss`` command imports ``sss_addon.cli``
without Blender).
"""
