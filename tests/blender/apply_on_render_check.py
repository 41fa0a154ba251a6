"""Render a .blend with Apply on Render set in it, through the extension installed from its zip.

Run by test_apply_on_render.py in its own Python process (``blender -b
scene.blend -a`` through the ``bpy`` module): BLENDER_USER_RESOURCES must be
set before bpy is imported, and the installed add-on must not meet the
``cvsss`` package the other tests register. Prints Blender's and the add-on's
output, then one line ``REPORT <json>``. With ``CVSSS_BACKGROUND_COMPILE=1`` the
report also tells how the numba passes were prepared (see
``background_report``).

Usage: python apply_on_render_check.py <zip> <work folder> <scene.blend>
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
        "background": background_report(),
    }
    prefs.extensions.repos.remove(repo)
    print("REPORT " + json.dumps(report), flush=True)


def background_report() -> dict | None:
    """The installed add-on's background compile (None when it started none): its
    command line, and once it has ended, whether it stamped the cache complete; and
    how this process got the sampling kernel's builds (numba's cache hits and misses)."""
    found = [name for name in sys.modules if name.endswith(".sss_addon.precompile")]
    if not found:
        return None
    package = found[0].removesuffix(".sss_addon.precompile")
    precompile = sys.modules[found[0]]
    process = precompile._background.get("process")
    if process is None:
        return None
    code = process.wait(600)  # it goes on after the job's kernels; the stamp comes last
    cache = sys.modules[package + ".core.backends.cache"]
    kernels = sys.modules[package + ".core.backends.numba.sampling"]
    builds = {}
    for name in ("pixel_sums", "pixel_sums_serial"):
        stats = getattr(kernels, name).stats
        builds[name] = [sum(stats.cache_hits.values()), sum(stats.cache_misses.values())]
    return {
        "args": process.args[3:],  # package name, pixels
        "package": package,
        "exit": code,
        "stamped": cache.is_complete(),
        "builds": builds,
    }


if __name__ == "__main__":
    main(*sys.argv[1:4])
