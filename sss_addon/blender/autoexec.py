"""The Python in a .blend that Blender did not run because auto-execution is off.

Blender runs a file's registered text blocks (Text ▸ Register, ``Text.use_module``)
when it loads the file, and its drivers' Python expressions when it evaluates them,
only with Python auto-execution on: the *Auto Run Python Scripts* preference, the
file browser's *Trust* option (``wm.open_mainfile(use_scripts=True)``), or
``blender -y`` (``-Y``: off whatever the preference). Off, it skips both and sets
``bpy.app.autoexec_fail`` (reset when a file is loaded). Not every expression
needs it: the simple-expression evaluator runs arithmetic on the driver's
variables, ``frame`` and a few math functions (``Driver.is_simple_expression``),
and a restricted check lets through expressions made of whitelisted names and
operations only (``max([frame, 1])``); what fails that check (``__import__``,
attribute access such as ``bpy.context.scene``, names a skipped script would have
defined) is not run: the driver gives 0 (clamped to the property's range: a camera
lens becomes 1 mm) and is marked invalid (``Driver.is_valid`` false). (Blender's
``bpy_driver.cc``: ``BPY_driver_exec``; ``bpy_interface.cc``:
``BPY_modules_load_user``.)

So what was skipped is read from what Blender did: the registered text blocks,
and the scripted drivers it marked invalid, when ``autoexec_fail`` says it
skipped something. A driver only the render evaluates (its object hidden in the
viewport) is not marked before the render, so it is not named.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy

#: Drivers named in the one-line warning; the rest are counted.
NAMED = 3


@dataclass
class Skipped:
    """What Blender did not run: ``drivers`` as ``"Owner: data_path[i]"``, ``scripts`` as
    text block names."""

    drivers: list[str] = field(default_factory=list)
    scripts: list[str] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(self.drivers or self.scripts)

    def describe(self) -> str:
        """``2 Python driver(s) (Cube: location[0], …) and script 'rig.py'``."""
        parts = []
        if self.drivers:
            named = ", ".join(self.drivers[:NAMED])
            more = f", {len(self.drivers) - NAMED} more" if len(self.drivers) > NAMED else ""
            parts.append(f"{len(self.drivers)} Python driver(s) ({named}{more})")
        if self.scripts:
            noun = "script" if len(self.scripts) == 1 else "scripts"
            parts.append(f"{noun} {', '.join(map(repr, self.scripts))}")
        return " and ".join(parts)


def _owners():
    """Every datablock of the file, and the node trees embedded in them."""
    for prop in bpy.types.BlendData.bl_rna.properties:
        if prop.type != "COLLECTION":
            continue
        for block in getattr(bpy.data, prop.identifier):
            yield block.name, block
            tree = getattr(block, "node_tree", None)
            if tree is not None:
                yield block.name, tree


def _target(owner, fcurve) -> str:
    """``data_path`` and, for an array property, ``[index]``."""
    path = fcurve.data_path
    try:
        value = owner.path_resolve(path, False)
    except (ValueError, TypeError):
        return f"{path}[{fcurve.array_index}]"
    return f"{path}[{fcurve.array_index}]" if hasattr(value, "__len__") else path


def _needs_python(driver) -> bool:
    if driver.type != "SCRIPTED" or driver.is_simple_expression:
        return False
    try:  # compiled only, never run: a syntax error fails with auto-execution on too
        compile(driver.expression, "<driver>", "eval")
    except (SyntaxError, ValueError):
        return False
    return True


def skipped() -> Skipped:
    """The drivers and registered scripts of the open file that Blender did not run;
    empty when it skipped nothing (auto-execution on, or nothing needing it)."""
    found = Skipped()
    if not bpy.app.autoexec_fail:
        return found
    found.scripts = [text.name for text in bpy.data.texts if text.use_module]
    for name, owner in _owners():
        anim = getattr(owner, "animation_data", None)
        if anim is None:
            continue
        for fcurve in anim.drivers:
            driver = fcurve.driver
            if not driver.is_valid and _needs_python(driver):
                found.drivers.append(f"{name}: {_target(owner, fcurve)}")
    return found


def warning(hint: str) -> str | None:
    """The one warning line about what was skipped, ending with ``hint`` (how to run
    them); None when nothing was."""
    found = skipped()
    if not found:
        return None
    verb = "is" if not found.drivers and len(found.scripts) == 1 else "are"
    return f"warning: Python auto-execution is off: {found.describe()} {verb} not run; {hint}"


def panel_note() -> str | None:
    """A short line for the panel when Blender skipped Python of this file."""
    if not bpy.app.autoexec_fail:
        return None
    return "Auto Run off: this file's Python drivers/scripts do not run"
