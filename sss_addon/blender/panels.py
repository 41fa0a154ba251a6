"""Panels: Properties ▸ Render (parameters, actions, last-frame statistics) and
Properties ▸ Material (whether the material takes part and its Burley shape)."""

import bpy
from bpy.types import Panel

from ...core.backends import select as mc_backend
from ...core.methods import METHODS
from . import autoexec
from . import materials as sss_materials
from .apply_on_render.notes import scene_notes
from .apply_on_render.session import warm_up_pays
from .properties import QUALITY_METHODS, param_properties


class _RenderPanel:
    """Properties ▸ Render panels: location and the split layout."""

    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_options = {"DEFAULT_CLOSED"}  # noqa: RUF012


def _split(layout):
    """``layout`` set up as Blender's property panels draw (labels left, no decorators)."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    return layout


class SSS_PT_render(_RenderPanel, Panel):
    bl_label = "Screen-Space Subsurface (cvsss)"
    bl_idname = "SSS_PT_render"

    def draw(self, context):
        layout, s = _split(self.layout), context.scene.sss_settings
        method = METHODS.get(s.method)

        col = layout.column()
        col.prop(s, "apply_on_render")
        sub = col.column()
        sub.active = s.apply_on_render
        row = sub.row()
        row.prop(s, "warmup_frames")
        row.active = s.apply_on_render and warm_up_pays(s.method)  # temporal methods only
        row = sub.row()
        row.prop(s, "thin_walks")
        row.active = s.apply_on_render and context.scene.render.engine == "CYCLES"
        if s.apply_on_render:
            for text in scene_notes(context.scene):
                sub.label(text=text, icon="INFO")
        skipped = autoexec.panel_note()
        if skipped is not None:  # Blender's own render skips them too
            col.label(text=skipped, icon="ERROR")

        layout.prop(s, "method")
        row = layout.row()
        row.prop(s, "cv_mode")
        row.enabled = method is not None and method.adaptive
        row = layout.row()
        row.prop(s, "temporal_mode")
        row.active = method is not None and method.temporal == "guided"

        col = layout.column(align=True)
        col.prop(s, "quality")
        if s.quality == "PSNR":
            col.prop(s, "quality_psnr")
        elif s.quality == "SPP":
            col.prop(s, "quality_spp")
        if s.quality != "MANUAL" and s.method not in QUALITY_METHODS:
            col.label(text="Quality applies to Fixed and the adaptive methods", icon="INFO")
        manual = s.quality == "MANUAL"

        col = layout.column(align=True)
        col.active = method is not None and method.adaptive
        row = col.row()
        row.prop(s, "target_variance")
        row.enabled = manual
        col.prop(s, "eta")
        col.prop(s, "kappa")
        row = col.row()
        row.prop(s, "beta_min")
        row.enabled = manual
        col.prop(s, "beta_max")
        col.prop(s, "eps_u")
        sub = col.column(align=True)
        sub.active = method is not None and method.cv == "online"
        sub.prop(s, "eta_cv")
        sub.prop(s, "eps_alpha")

        col = layout.column(align=True)
        col.active = s.method == "separable"
        col.prop(s, "separable_kernel")
        col.prop(s, "separable_taps")
        col.prop(s, "separable_jitter")

        col = layout.column(align=True)
        row = col.row()
        row.prop(s, "fixed_spp")
        row.active = s.method == "fixed"
        row.enabled = manual
        col.prop(s, "use_reference")
        row = col.row()
        row.prop(s, "reference_spp")
        row.active = s.use_reference or s.method == "reference"
        col.prop(s, "seed")
        col.prop(s, "history_precision")
        col.prop(s, "exposure")

        col = layout.column()
        col.prop(s, "engine")
        col.prop(s, "use_normal_pass")
        row = col.row()
        row.prop(s, "use_denoise_passes")
        row.active = s.engine == "CYCLES"
        row = col.row()
        row.prop(s, "use_denoise_subsurface")
        row.active = s.engine == "EEVEE"
        col.prop(s, "use_ground_truth")
        sub = col.column(align=True)
        sub.active = s.use_ground_truth
        sub.prop(s, "ground_truth_samples")
        sub.prop(s, "ground_truth_every")
        sub.prop(s, "ground_truth_method")
        col.prop(s, "output_dir")
        col.prop(s, "overwrite")
        col.prop(s, "use_frame_range")
        sub = col.column(align=True)
        sub.active = s.use_frame_range
        sub.prop(s, "frame_start")
        sub.prop(s, "frame_end")

        layout.use_property_split = False
        row = layout.row(align=True)
        row.operator("sss.render_passes", icon="RENDER_STILL")
        row.operator("sss.apply_frame", icon="IMAGE_DATA")
        layout.operator("sss.render_sequence", icon="RENDER_ANIMATION")
        layout.operator_menu_enum("sss.build_demo", "scene_name", icon="SCENE_DATA")

        box = layout.box()
        if s.has_stats:
            box.label(text=f"Frame {s.last_frame} ({s.last_method})")
            box.label(text=f"Mean spp: {s.last_spp:.2f}")
            box.label(text=f"Sampling time: {s.last_sampling_ms:.2f} ms")
            box.label(text=f"PSNR: {s.last_psnr:.2f} dB" if s.last_psnr > 0 else "PSNR: –")
            if s.last_psnr_gt > 0:
                box.label(text=f"PSNR vs Cycles: {s.last_psnr_gt:.2f} dB")
            box.label(text=f"Backend: {mc_backend.describe(s.backend)}")
        else:
            box.label(text="No frame processed yet")


class SSS_PT_render_advanced(_RenderPanel, Panel):
    """Every parameter the command line takes that the main panel does not show."""

    bl_label = "Advanced"
    bl_idname = "SSS_PT_render_advanced"
    bl_parent_id = "SSS_PT_render"

    def draw(self, context):
        layout, s = _split(self.layout), context.scene.sss_settings
        layout.prop(s, "profile")
        col = layout.column(align=True)
        for name, (_, _, spec) in param_properties().items():
            if spec.advanced:
                row = col.row()
                row.prop(s, name)
                row.active = not name.startswith("separable_") or s.method == "separable"
                if name == "backend":
                    # Which implementation runs here (numba is missing where no wheel exists).
                    col.label(text=f"Runs: {mc_backend.describe(s.backend)}", icon="INFO")


class SSS_PT_material(Panel):
    bl_label = "Subsurface (cvsss)"
    bl_idname = "SSS_PT_material"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"
    bl_options = {"DEFAULT_CLOSED"}  # noqa: RUF012

    @classmethod
    def poll(cls, context):
        return getattr(context, "material", None) is not None

    def draw(self, context):
        layout = _split(self.layout)
        material = context.material
        m = material.sss_material
        layout.prop(m, "mode")
        row = layout.row()
        row.enabled = False
        row.prop(m, "participates")

        model = sss_materials.model_summary(material)
        box = layout.box()
        if model is None:
            box.label(text="No Principled BSDF", icon="INFO")
        else:
            replaced = m.use_override or m.preset != "NONE"
            box.active = not replaced
            box.label(text=f"Model: {model['label']} (the node's Subsurface Method)")
            if model["method"] == "BURLEY":
                box.label(text="Burley d from Principled BSDF (radius × scale × 0.25/π):")
                box.label(text="R {:.5g}  G {:.5g}  B {:.5g}".format(*model["d"]))
            else:
                box.label(text="Burley d fitted to Cycles' walk (albedo, radius, scale):")
                box.label(text="R {:.5g}  G {:.5g}  B {:.5g}".format(*model["d"]))
                box.label(text="Energy: R {:.3f}  G {:.3f}  B {:.3f}".format(*model["energy"]))
                box.label(text="× view angle and curvature, per pixel")
                if model["linked"]:
                    box.label(
                        text="Base Color textured: each frame's mean Diffuse Color is used",
                        icon="INFO",
                    )
            if replaced:
                box.label(text="Replaced by the override or preset below", icon="INFO")
        layout.prop(m, "use_override")
        col = layout.column()
        col.active = m.use_override
        col.prop(m, "d_override")
        layout.prop(m, "preset")
        if m.preset != "NONE":
            layout.prop(m, "preset_scale")
            d = sss_materials.preset_shape(material, context.scene)
            if d is None:
                layout.label(text="Preset stored; the core has no preset table", icon="INFO")
            else:
                layout.label(text="Preset d: R {:.5g}  G {:.5g}  B {:.5g}".format(*d))


classes = (SSS_PT_render, SSS_PT_render_advanced, SSS_PT_material)
register, unregister = bpy.utils.register_classes_factory(classes)
