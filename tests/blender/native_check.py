"""Render a .blend with Apply on Render set in it, through the extension installed from its zip.

Run by test_apply_on_render.py in its own Python process (``blender -b
scene.blend -a`` through the ``bpy`` module): BLENDER_USER_RESOURCES must be
set before bpy is imported, and the installed add-on must not meet the
``cvsss`` package the other tests register. Prints Blender's and the add-on's
output, then one line ``REPORT <json>``.

Usage: python native_check.py <zip> <work folder> <scene.blend>
"""

import json
import os
import sys

REPO = "cvsss_test"


def main(zip_path: str, work: str, blend: str) -> None:
    os.environ["BLENDER_USER_RESOURCES"] = os.path.join(work, "user")  # before bpy
    import bpy

    prefs = bpy.context.preferences
    repo = prefs.extensions.repos.new(
        name="cvsss test",
        module=REPO,
        custom_directory=os.path.join(work, "repo"),
        source="USER",
    )
    installed = bpy.ops.extensions.package_install_files(
        filepath=zip_path, repo=REPO, enable_on_install=True
    )
    bpy.ops.wm.open_mainfile(filepath=blend)
    scene = bpy.context.scene
    result = bpy.ops.render.render(animation=True)
    sys.stdout.flush()
    report = {
        "install": sorted(installed),
        "render": sorted(result),
        "apply_on_render": scene.sss_settings.apply_on_render,
        "scenes": sorted(s.name for s in bpy.data.scenes),
        "file_format": scene.render.image_settings.file_format,
    }
    prefs.extensions.repos.remove(repo)
    print("REPORT " + json.dumps(report), flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:4])
