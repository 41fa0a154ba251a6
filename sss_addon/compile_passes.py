"""Compile the numba passes into the disk cache in a process of their own, then exit.

Started by :func:`sss_addon.precompile.start_background` as
``python compile_passes.py <package folder> <package name> [<pixels>]``: it imports the
extension's ``core`` under the same module names as the process that started
it (``bl_ext.user_default.cvsss`` inside Blender), so the cache entries it
writes are the ones that process loads, and runs ``core.backends.compile.compile_all``.
With ``pixels`` (the job's frame size, H·W) it first compiles what frames of
that size take and prints ``{"ready": s}``, the moment the job may load them,
then goes on with the rest. Every kernel compiled, it stamps the cache
complete and prints ``{"seconds": s}``; on failure ``{"error": "..."}``. It
runs at low priority when no job waits for it (no ``pixels``), and never
imports bpy.
"""

import importlib
import importlib.util
import json
import os
import sys
import types


def main() -> None:
    root, package = sys.argv[1], sys.argv[2]
    pixels = int(sys.argv[3]) if len(sys.argv) > 3 else None
    # Run as a script, this folder came first on sys.path: its modules are not top-level.
    if sys.path and os.path.abspath(sys.path[0]) == os.path.dirname(os.path.abspath(__file__)):
        del sys.path[0]
    if pixels is None:  # nobody waits (the add-on registered): below the UI's priority
        try:
            os.nice(10)  # POSIX; on Windows the parent sets a lower priority class
        except (AttributeError, OSError):
            pass
    try:
        parts = package.split(".")
        for i in range(1, len(parts)):  # e.g. bl_ext, bl_ext.user_default: empty parents
            name = ".".join(parts[:i])
            if name not in sys.modules:
                parent = types.ModuleType(name)
                parent.__path__ = []
                sys.modules[name] = parent
        spec = importlib.util.spec_from_file_location(
            package, os.path.join(root, "__init__.py"), submodule_search_locations=[root]
        )
        module = importlib.util.module_from_spec(spec)
        sys.modules[package] = module
        spec.loader.exec_module(module)
        backend = importlib.import_module(package + ".core.backends.compile")
        if pixels is not None:
            print(json.dumps({"ready": backend.compile_all(pixels)}), flush=True)
        out = {"seconds": backend.compile_all()}
    except Exception as exc:  # reported to the parent, which compiles on its own
        out = {"error": f"{type(exc).__name__}: {exc}"}
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
