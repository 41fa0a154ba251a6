"""Install the built extension zip into a throw-away repository and report on it.

Run by test_addon_extension.py in its own Python process, because
BLENDER_USER_RESOURCES must be set before bpy is imported and the installed
add-on (``bl_ext.cvsss_test.cvsss``) must not meet the ``cvsss`` package the
other tests register. Prints one line ``REPORT <json>``.

With ``--no-numba`` numba and llvmlite cannot be imported (an import hook refuses
them, as if the platform had no wheel of them: the windows-arm64 zip), and the
background compile is left on, so that the report shows what the add-on decides.

Usage: python extension_check.py <zip> <work folder> [--no-numba]
"""

import json
import os
import sys

REPO = "cvsss_test"
MOD = f"bl_ext.{REPO}.cvsss"


def plain(value):
    if isinstance(value, str | int | float | bool):
        return value
    if isinstance(value, set | frozenset):
        return sorted(value)
    return [plain(v) for v in value]


def group_state(group) -> dict:
    out = {}
    for prop in group.bl_rna.properties:
        if prop.identifier == "rna_type":
            continue
        value = getattr(group, prop.identifier)
        default = (
            prop.default_array
            if getattr(prop, "is_array", False)
            else getattr(prop, "default", None)
        )
        out[prop.identifier] = {
            "value": plain(value),
            "default": None if default is None else plain(default),
            "description": prop.description,
            "min": getattr(prop, "hard_min", None),
            "max": getattr(prop, "hard_max", None),
        }
    return out


class _Refuse:
    """An import hook: the modules ``names`` (and their submodules) are not installed."""

    def __init__(self, names):
        self.names = set(names)

    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in self.names:
            raise ModuleNotFoundError(f"No module named {name!r} (refused by extension_check)")
        return None


def main(zip_path: str, work: str, numba: bool = True) -> None:
    os.environ["BLENDER_USER_RESOURCES"] = os.path.join(work, "user")  # before bpy
    records = []
    if not numba:
        sys.meta_path.insert(0, _Refuse(("numba", "llvmlite")))
        os.environ["CVSSS_BACKGROUND_COMPILE"] = "1"  # the add-on's own decision, not ours
        import logging

        handler = logging.Handler()
        handler.emit = lambda r: records.append([r.levelname, r.getMessage()])
        logging.getLogger("cvsss").addHandler(handler)
        logging.getLogger("cvsss").setLevel(logging.INFO)
    import bpy

    # isort: split
    import addon_utils  # Blender's own module, importable once bpy is loaded

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    prefs = bpy.context.preferences
    types_before = set(dir(bpy.types))
    scene_props_before = {p.identifier for p in bpy.types.Scene.bl_rna.properties}
    material_props_before = {p.identifier for p in bpy.types.Material.bl_rna.properties}

    repo_dir = os.path.join(work, "repo")
    repo = prefs.extensions.repos.new(
        name="cvsss test", module=REPO, custom_directory=repo_dir, source="USER"
    )
    report = {}
    report["install"] = sorted(
        bpy.ops.extensions.package_install_files(
            filepath=zip_path, repo=REPO, enable_on_install=True
        )
    )
    # Blender installs the zip's wheels into extensions/.local; put that first on the
    # path so the add-on's lazy import of numba takes the bundled wheel, not the venv's.
    local = [p for p in sys.path if os.path.join("extensions", ".local") in p]
    report["wheel_site"] = sorted(
        name.split("-")[0]
        for site in local
        if os.path.isdir(site)
        for name in os.listdir(site)
        if name.endswith(".dist-info")
    )
    report["numba_preloaded"] = "numba" in sys.modules
    sys.path[:0] = [p for p in local if os.path.isdir(p)]
    report["enabled"] = MOD in prefs.addons
    module = sys.modules[MOD]
    report["module_file"] = module.__file__
    report["installed_files"] = sorted(os.listdir(os.path.join(repo_dir, "cvsss")))
    report["operators"] = sorted(op for op in dir(bpy.ops.sss) if not op.startswith("_"))
    report["panels"] = sorted(name for name in dir(bpy.types) if name.startswith("SSS_PT_"))
    scene = bpy.context.scene
    report["settings"] = group_state(scene.sss_settings)
    material = bpy.data.materials.new("check")
    report["material"] = group_state(material.sss_material)
    properties = sys.modules[MOD + ".sss_addon.blender.properties"]
    report["params"] = properties.settings_to_params(scene.sss_settings).to_dict()
    report["core_module"] = sys.modules[MOD + ".core.params"].__file__

    # The installed copy works end to end: a one-frame 24x16 render through the operators.
    bpy.ops.sss.build_demo(scene_name="flash")
    scene.render.engine = "CYCLES"
    scene.render.resolution_x, scene.render.resolution_y = 24, 16
    scene.cycles.samples = 1
    s = scene.sss_settings
    s.output_dir = os.path.join(work, "out")
    s.use_frame_range = True
    s.frame_start = s.frame_end = 1
    s.use_reference = False
    report["render"] = sorted(bpy.ops.sss.render_sequence())
    report["outputs"] = sorted(os.listdir(s.output_dir))
    report["images"] = sorted(img.name for img in bpy.data.images if img.name.startswith("SSS "))
    # The render went through the compiled kernel, imported from the bundled wheel.
    backend = sys.modules[MOD + ".core.backends.select"]
    report["backend"] = backend.describe(s.backend)
    kernel = sys.modules.get(MOD + ".core.backends.numba.sampling")
    report["kernel_signatures"] = (
        0
        if kernel is None
        else sum(len(k.signatures) for k in (kernel.pixel_sums, kernel.pixel_sums_serial))
    )
    report["numba_file"] = getattr(sys.modules.get("numba"), "__file__", None)
    report["llvmlite_file"] = getattr(sys.modules.get("llvmlite"), "__file__", None)
    report["background_compile"] = bool(sys.modules[MOD + ".sss_addon.precompile"]._background)
    report["log"] = records

    addon_utils.disable(MOD, default_set=True)
    report["enabled_after"] = MOD in prefs.addons
    report["types_left"] = sorted(set(dir(bpy.types)) - types_before)
    report["scene_props_left"] = sorted(
        {p.identifier for p in bpy.types.Scene.bl_rna.properties} - scene_props_before
    )
    report["material_props_left"] = sorted(
        {p.identifier for p in bpy.types.Material.bl_rna.properties} - material_props_before
    )
    report["operators_left"] = sorted(op for op in dir(bpy.ops.sss) if not op.startswith("_"))
    report["handlers_left"] = sorted(
        f"{name}: {handler.__module__}.{handler.__name__}"
        for name in dir(bpy.app.handlers)
        if isinstance(getattr(bpy.app.handlers, name), list)
        for handler in getattr(bpy.app.handlers, name)
        if getattr(handler, "__module__", "").startswith(MOD)
    )
    bpy.ops.extensions.package_uninstall(repo_directory=repo_dir, pkg_id="cvsss")
    report["uninstalled"] = not os.path.exists(os.path.join(repo_dir, "cvsss"))
    prefs.extensions.repos.remove(repo)
    print("REPORT " + json.dumps(report))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], numba="--no-numba" not in sys.argv[3:])
