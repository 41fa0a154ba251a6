"""``sss.build_demo``: build a demo scene from ``demo_blend.scenes`` into the current file."""

import bpy
from bpy.props import EnumProperty
from bpy.types import Operator

from ..demo_blend import scenes

# Blender keeps only pointers to the strings of dynamic enum items: hold them here.
_ITEMS: list[tuple[str, str, str]] = []


def _items(_self, _context):
    _ITEMS[:] = [(name, name.title(), text) for name, text in scenes.describe().items()]
    return _ITEMS


class SSS_OT_build_demo(Operator):
    """Build a deterministic demo scene into this file; sets the render settings (Cycles, 320×180, frames, samples) and bakes its particles"""

    bl_idname = "sss.build_demo"
    bl_label = "Build Demo Scene"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012

    scene_name: EnumProperty(name="Demo", description="Demo scene to build", items=_items)

    def execute(self, context):
        try:
            collection = scenes.build(self.scene_name, context.scene)
        except Exception as exc:
            self.report({"ERROR"}, f"cannot build demo {self.scene_name!r}: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Built demo {self.scene_name!r} in collection {collection.name!r}")
        return {"FINISHED"}


classes = (SSS_OT_build_demo,)
register, unregister = bpy.utils.register_classes_factory(classes)
