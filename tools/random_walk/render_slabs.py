"""Path-traced subsurface profiles of one Principled material, rendered by Cycles on the CPU.

Each *case* (one JSON object per line of the case file, see :data:`DEFAULTS`)
renders one image to ``OUT/<name>.exr`` (multilayer: Combined, Diffuse
Color, Diffuse Direct and Indirect) and writes ``OUT/<name>.json`` (the case
as rendered, with the Blender version and the render time). A case whose
record exists and matches is skipped, so a grid can be rendered in pieces.

Geometries
----------
``slab``
    A flat box (``slab_size`` wide, ``slab_depth`` deep, top face at z = 0)
    seen from straight above by an orthographic camera, lit by a sun straight
    down (angle 0: parallel light, irradiance ``E0 = π`` so that a white
    Lambertian surface has radiance 1). An occluder, invisible to every ray
    but shadow rays, shades the half-plane x < 0: the image is the material's
    *edge response* across a perfectly sharp shadow edge at x = 0 (the image
    centre). Every row sees the same edge, so a column mean over the rows is
    one point of the edge response with W·H·spp paths per image. The sun is
    invisible to glossy rays, so Combined holds the subsurface (and diffuse)
    light only. Without the occluder (``"occluder": false``) the whole slab is
    lit: its radiance is the material's total reflectance (times E0/π = 1).
``sphere``
    A sphere of ``sphere_radius`` at the origin, seen by an orthographic
    camera from −y, lit by a sun from +x (the terminator runs down the
    image centre) or from ``sun_dir``: where curvature changes the profile. In a
    uniform white world (``world_strength`` 1, ``sun_strength`` 0) every point
    is lit alike: Diffuse Direct + Indirect (Blender divides them by Diffuse
    Color) is then the reflectance over the albedo pass at each view angle.

Per channel the material's Base Color is ``albedo`` and its Subsurface Radius
``radius`` (with Subsurface Scale ``scale``): the three channels are three
independent experiments in one image (Cycles' channels share paths but not
their expectations).

Run with bpy's Python::

    nice -n 10 python tools/random_walk/render_slabs.py CASES.jsonl OUT [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import bpy

#: Every key a case may set, with its default. Lengths in scene units.
DEFAULTS = {
    "name": None,  # output file stem (required)
    "geometry": "slab",  # "slab" or "sphere"
    "method": "RANDOM_WALK",  # Principled subsurface_method
    "albedo": [0.8, 0.8, 0.8],  # Base Color, linear
    "radius": [1.0, 1.0, 1.0],  # Subsurface Radius
    "scale": 0.05,  # Subsurface Scale
    "ior": 1.5,  # IOR (Random Walk's entry refraction)
    "roughness": 0.5,  # Roughness (Random Walk's entry: GGX alpha = roughness²)
    "subsurface_ior": 1.4,  # Subsurface IOR (Random Walk (Skin) only)
    "anisotropy": 0.0,  # Subsurface Anisotropy
    "width": 256,  # pixels
    "height": 16,
    "pixel": 0.001,  # scene units per pixel (orthographic)
    "samples": 256,
    "seed": 0,
    "slab_size": 40.0,
    "slab_depth": 4.0,
    "sphere_radius": 0.05,
    "sun_dir": None,  # direction *to* the sun; default: +z (slab), +x (sphere)
    "sun_strength": math.pi,  # irradiance on a surface facing the sun, W/m² (0: no sun)
    "world_strength": 0.0,  # radiance of a uniform white world (1: Lambertian radiance = A)
    "occluder": True,  # slab: shade x < 0 (False: the whole slab is lit)
    "view_angle": 0.0,  # slab: camera tilted this many degrees from the normal (about y)
}


def _case(raw: dict) -> dict:
    unknown = set(raw) - set(DEFAULTS)
    if unknown:
        raise SystemExit(f"unknown case keys: {', '.join(sorted(unknown))}")
    case = {**DEFAULTS, **raw}
    if not case["name"]:
        raise SystemExit("every case needs a 'name'")
    if case["geometry"] not in ("slab", "sphere"):
        raise SystemExit(f"geometry must be slab or sphere, got {case['geometry']!r}")
    if case["sun_dir"] is None:
        case["sun_dir"] = [0.0, 0.0, 1.0] if case["geometry"] == "slab" else [1.0, 0.0, 0.0]
    return case


def _reset() -> bpy.types.Scene:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def _material(case: dict) -> bpy.types.Material:
    mat = bpy.data.materials.new("probe")
    mat.use_nodes = True  # still needed in 5.0 for a new material's node tree
    node = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    node.subsurface_method = case["method"]
    # By identifier: a socket the method hides (Subsurface IOR outside Skin) is not
    # found by name, but Cycles still reads its value.
    inputs = {s.identifier: s for s in node.inputs}
    inputs["Base Color"].default_value = (*case["albedo"], 1.0)
    inputs["Subsurface Weight"].default_value = 1.0
    inputs["Subsurface Radius"].default_value = case["radius"]
    inputs["Subsurface Scale"].default_value = case["scale"]
    inputs["IOR"].default_value = case["ior"]
    inputs["Roughness"].default_value = case["roughness"]
    inputs["Subsurface IOR"].default_value = case["subsurface_ior"]
    inputs["Subsurface Anisotropy"].default_value = case["anisotropy"]
    return mat


def _only_shadows(obj) -> None:
    for attr in (
        "visible_camera",
        "visible_diffuse",
        "visible_glossy",
        "visible_transmission",
        "visible_volume_scatter",
    ):
        setattr(obj, attr, False)
    obj.visible_shadow = True


def _look_at(obj, direction) -> None:
    from mathutils import Vector

    obj.rotation_euler = Vector(direction).to_track_quat("-Z", "Y").to_euler()


def build(case: dict) -> bpy.types.Scene:
    scene = _reset()
    scene.world = bpy.data.worlds.new("black")
    scene.world.use_nodes = True
    background = scene.world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)  # a new world's is grey
    background.inputs["Strength"].default_value = case["world_strength"]
    mat = _material(case)
    w, h, px = case["width"], case["height"], case["pixel"]

    if case["geometry"] == "slab":
        s, depth = case["slab_size"], case["slab_depth"]
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0, 0, -depth / 2))
        body = bpy.context.object
        body.scale = (s, s, depth)
        if case["occluder"]:
            # Shades x < 0 (a plane from x = -s to 0, above the slab).
            bpy.ops.mesh.primitive_plane_add(size=1.0, location=(-s, 0, 0.5))
            occ = bpy.context.object
            occ.scale = (2 * s, 4 * s, 1)
            _only_shadows(occ)
        t = math.radians(case["view_angle"])
        cam_loc = (5.0 * math.sin(t), 0.0, 5.0 * math.cos(t))
        cam_dir = (-math.sin(t), 0.0, -math.cos(t))
    else:
        bpy.ops.mesh.primitive_uv_sphere_add(
            radius=case["sphere_radius"], segments=256, ring_count=128
        )
        body = bpy.context.object
        bpy.ops.object.shade_smooth()
        cam_loc, cam_dir = (0.0, -5.0, 0.0), (0.0, 1.0, 0.0)
    body.data.materials.append(mat)

    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = max(w, h) * px
    cam_data.clip_end = 100.0
    cam = bpy.data.objects.new("cam", cam_data)
    scene.collection.objects.link(cam)
    cam.location = cam_loc
    if case["geometry"] == "slab":
        # Tilted about y only: image x stays across the edge (x on the slab), y along it.
        cam.rotation_euler = (0.0, math.radians(case["view_angle"]), 0.0)
    else:
        _look_at(cam, cam_dir)
    scene.camera = cam

    if case["sun_strength"] > 0:
        sun_data = bpy.data.lights.new("sun", "SUN")
        sun_data.energy = case["sun_strength"]
        sun_data.angle = 0.0
        sun = bpy.data.objects.new("sun", sun_data)
        scene.collection.objects.link(sun)
        _look_at(sun, [-v for v in case["sun_dir"]])
        sun.visible_glossy = False  # no specular highlight: Combined is the subsurface light

    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = w, h, 100
    r.film_transparent = False
    c = scene.cycles
    c.device = "CPU"
    c.samples = case["samples"]
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = case["seed"]
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.time_limit = 0.0
    scene.view_settings.view_transform = "Standard"
    layer = scene.view_layers[0]
    layer.use_pass_diffuse_color = True
    layer.use_pass_diffuse_direct = True
    layer.use_pass_diffuse_indirect = True
    r.image_settings.media_type = "MULTI_LAYER_IMAGE"  # Blender 5.0: before the format
    r.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    r.image_settings.color_depth = "32"
    r.image_settings.exr_codec = "ZIP"
    return scene


def render(case: dict, out: Path, threads: int) -> dict:
    scene = build(case)
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    scene.render.filepath = str(out / f"{case['name']}.exr")
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    seconds = time.perf_counter() - t0
    return {**case, "blender": bpy.app.version_string, "seconds": round(seconds, 2)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("cases", type=Path, help="JSON lines, one case each")
    ap.add_argument("out", type=Path)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    lines = [ln for ln in args.cases.read_text().splitlines() if ln.strip()]
    cases = [_case(json.loads(ln)) for ln in lines]
    for i, case in enumerate(cases, 1):
        record = args.out / f"{case['name']}.json"
        if record.exists() and (args.out / f"{case['name']}.exr").exists():
            old = json.loads(record.read_text())
            if {k: old.get(k) for k in case} == case:
                continue
        done = render(case, args.out, args.threads)
        record.write_text(json.dumps(done, indent=1) + "\n")
        print(f"[{i}/{len(cases)}] {case['name']}: {done['seconds']} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
