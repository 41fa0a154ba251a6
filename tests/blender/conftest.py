"""bpy lane: the add-on in real headless Blender (the ``bpy`` module).

Blender reads ``BLENDER_USER_RESOURCES`` once, when bpy is first imported, so
this file points it at a throw-away folder at import time: pytest imports
conftest files before any test module, and bpy is imported in this process
only by tests/blender (other lanes render in subprocesses, which inherit the
variable). Nothing touches the user's real Blender configuration.
"""

import atexit
import json
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np
import pytest

_USER = tempfile.mkdtemp(prefix="cvsss-blender-user-")
os.environ["BLENDER_USER_RESOURCES"] = _USER
atexit.register(shutil.rmtree, _USER, ignore_errors=True)

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def addon():
    """The cvsss package registered once for the session (as Blender would an add-on)."""
    import bpy  # noqa: F401

    import cvsss

    cvsss.register()
    yield cvsss
    cvsss.unregister()


@pytest.fixture
def fresh(addon):
    """An empty factory scene rendering with Cycles on the CPU."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    return scene


@pytest.fixture
def demo(fresh, tmp_path):
    """The flash demo at 48x32, 4 samples, frames 1–3, output in tmp_path/out."""
    import bpy

    bpy.ops.sss.build_demo(scene_name="flash")
    scene = fresh
    scene.render.resolution_x, scene.render.resolution_y = 48, 32
    scene.render.resolution_percentage = 100
    scene.cycles.samples = 4
    s = scene.sss_settings
    s.output_dir = str(tmp_path / "out")
    s.use_frame_range = True
    s.frame_start, s.frame_end = 1, 3
    s.method = "as_ocv"
    s.target_variance = 1e-6  # forces counts to vary between beta_min and beta_max
    s.reference_spp = 64
    return scene


@pytest.fixture
def demo_blend(demo, tmp_path):
    """The :func:`demo` scene saved with its cvsss settings (no reference) as a .blend."""
    import bpy

    demo.sss_settings.use_reference = False
    path = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def _run_check_script(name: str, *args, cwd: Path) -> tuple[dict, str]:
    """Run ``tests/blender/<name>`` in a fresh Python (no user resources); the run must
    exit 0. Returns the JSON of its ``REPORT `` line and its whole stdout."""
    env = {k: v for k, v in os.environ.items() if k != "BLENDER_USER_RESOURCES"}
    run = subprocess.run(
        [sys.executable, str(Path(__file__).with_name(name)), *map(str, args)],
        capture_output=True,
        text=True,
        check=False,
        timeout=600,
        env=env,
        cwd=cwd,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    (line,) = (ln for ln in run.stdout.splitlines() if ln.startswith("REPORT "))
    return json.loads(line.removeprefix("REPORT ")), run.stdout


@pytest.fixture(scope="session")
def check_script():
    """``check_script(name, *args, cwd=…)``: run a check script -> (report, stdout)."""
    return _run_check_script


# -- scene state snapshots (independent of the add-on's own snapshot code) ------------------
_SCALARS = {"BOOLEAN", "INT", "FLOAT", "STRING", "ENUM"}


def _plain(value):
    if isinstance(value, str | int | float | bool) or value is None:
        return value
    if isinstance(value, set | frozenset):
        return tuple(sorted(value))
    try:
        return tuple(_plain(v) for v in value)
    except TypeError:
        return repr(value)


def _props(struct, prefix: str, out: dict, depth: int = 0) -> None:
    for prop in struct.bl_rna.properties:
        ident = prop.identifier
        if ident == "rna_type":
            continue
        if prop.type in _SCALARS:
            try:
                out[f"{prefix}.{ident}"] = _plain(getattr(struct, ident))
            except (AttributeError, RuntimeError):
                pass
        elif prop.type == "POINTER" and depth < 2 and ident != "depsgraph":
            if ident == "linear_colorspace_settings" and not struct.has_linear_colorspace:
                # Unused by non-linear formats; a fresh scene holds an unset value that
                # RNA cannot write back, and Blender resets it when a linear format is chosen.
                continue
            child = getattr(struct, ident, None)
            if child is not None and not hasattr(child, "users"):  # nested structs, not IDs
                _props(child, f"{prefix}.{ident}", out, depth + 1)


def _tree(tree, prefix: str, out: dict, seen: set) -> None:
    if tree is None or tree.as_pointer() in seen:
        return
    seen.add(tree.as_pointer())
    for node in tree.nodes:
        for i, socket in enumerate(node.inputs):
            if hasattr(socket, "default_value"):
                out[f"{prefix}.{node.name}.in{i}.{socket.name}"] = _plain(socket.default_value)
        if node.bl_idname in ("ShaderNodeGroup", "CompositorNodeGroup"):
            _tree(node.node_tree, f"{prefix}>{node.name}", out, seen)
        for attr in ("scene", "layer"):  # what a Render Layers node reads
            if node.bl_idname == "CompositorNodeRLayers":
                value = getattr(node, attr)
                out[f"{prefix}.{node.name}.{attr}"] = getattr(value, "name", value)
        image = getattr(node, "image", None)
        if image is not None:  # the image a texture node shows, and what it is
            out[f"{prefix}.{node.name}.image"] = (
                image.as_pointer(),
                image.name,
                image.source,
                image.filepath,
                image.is_float,
            )
    out[f"{prefix}.links"] = tuple(
        sorted(
            (
                lk.from_node.name,
                lk.from_socket.identifier,
                lk.to_node.name,
                lk.to_socket.identifier,
                lk.is_muted,
            )
            for lk in tree.links
        )
    )
    anim = tree.animation_data
    if anim is not None:
        out[f"{prefix}.drivers"] = tuple((d.data_path, d.mute) for d in anim.drivers)


def scene_state(scene) -> dict:
    """Everything the pass render may touch: materials (every node input, links with
    their mute flag, texture nodes' images, pass index), object pass indices, material
    slots and the add-on's properties (``cvsss…``), node groups, view layers (pass flags), render/image/Cycles
    settings, the compositor's node group (nodes, links, what its Render Layers read),
    frame."""
    import bpy

    out: dict = {}
    for material in bpy.data.materials:
        out[f"mat:{material.name}.pass_index"] = material.pass_index
        _tree(material.node_tree, f"mat:{material.name}", out, set())
    for obj in bpy.data.objects:
        out[f"obj:{obj.name}.pass_index"] = obj.pass_index
        out[f"obj:{obj.name}.props"] = {
            key: repr(obj[key]) for key in obj.keys() if key.startswith("cvsss")
        }
        out[f"obj:{obj.name}.slots"] = [
            (slot.link, slot.material.name if slot.material else None)
            for slot in obj.material_slots
        ]
    out["node_groups"] = sorted(group.name for group in bpy.data.node_groups)
    for layer in scene.view_layers:
        _props(layer, f"layer:{layer.name}", out)
        if getattr(layer, "cycles", None) is not None:
            _props(layer.cycles, f"layer:{layer.name}.cycles", out)
    _props(scene.render, "render", out)
    _props(scene.render.image_settings, "render.image_settings", out)
    _props(scene.cycles, "cycles", out)
    group = getattr(scene, "compositing_node_group", None)
    out["compositor"] = group.name if group is not None else None
    _tree(group, "compositor", out, set())
    out["frame_current"] = scene.frame_current
    out["frame_subframe"] = scene.frame_subframe
    out["camera"] = scene.camera.name if scene.camera else None
    return out


def state_diff(before: dict, after: dict) -> list[str]:
    keys = sorted(set(before) | set(after))
    return [
        f"{k}: {before.get(k, '<missing>')!r} -> {after.get(k, '<missing>')!r}"
        for k in keys
        if before.get(k, "<missing>") != after.get(k, "<missing>")
    ]


@pytest.fixture
def snapshot():
    """Function scene -> state dict, and the diff of two states."""
    return scene_state, state_diff


def _walk_everywhere() -> None:
    import bpy

    for material in bpy.data.materials:
        for node in material.node_tree.nodes if material.node_tree else ():
            if node.bl_idname == "ShaderNodeBsdfPrincipled":
                node.subsurface_method = "RANDOM_WALK"


#: Subsurface Scale divisors that take the flash demo's thick parts beyond the
#: Christensen-Burley sizes Cycles renders whole (8 to 50 d): Suzanne (20.4 d of her skin
#: across) and the marble block (20 d) to 61 and 60 d, the apples (15 and 12 d) to 75
#: and 60 d.
THICKER = {"cvsss Skin": 3.0, "cvsss Marble": 3.0, "cvsss Apple": 5.0}


def _thick_parts() -> None:
    import bpy

    for name, divisor in THICKER.items():
        bsdf = bpy.data.materials[name].node_tree.nodes["Principled BSDF"]
        bsdf.inputs["Subsurface Scale"].default_value /= divisor


@pytest.fixture
def thick_parts():
    """Function () -> None that makes the flash demo's skin, marble and apples less
    translucent (:data:`THICKER`): Suzanne, the marble block and the apples go beyond the
    Christensen-Burley sizes Cycles renders whole, so the post renders them again; the
    marble top (2 cm: 6 d) keeps its rims at Cycles."""
    return _thick_parts


@pytest.fixture
def walk_everywhere():
    """Function () -> None that sets every Principled BSDF of the file to Random Walk
    (Blender's default), as a user switching a demo scene would."""
    return _walk_everywhere


# -- an independent denoise ------------------------------------------------------------------
def _image(name: str, rgb: np.ndarray, non_color: bool):
    import bpy

    height, width = rgb.shape[:2]
    rgba = np.ones((height, width, 4), np.float32)
    rgba[..., :3] = rgb
    image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
    image.colorspace_settings.name = "Non-Color" if non_color else "Linear Rec.709"
    image.pixels.foreach_set(np.ascontiguousarray(rgba[::-1]).reshape(-1))
    image.pack()
    return image


def _oidn(noisy, albedo, normal, prefilter: str, quality: str) -> np.ndarray:
    """Blender's Denoise node on ``noisy`` guided by ``albedo`` and ``normal`` ((H, W, 3)
    linear, top row first; a guide None is left unlinked) with the node's ``prefilter``
    and ``quality`` items: (H, W, 3) denoised. Built here, apart from the add-on's own
    code."""
    import bpy
    import OpenEXR

    scene = bpy.data.scenes.new("test denoise")
    tree = bpy.data.node_groups.new("test denoise", "CompositorNodeTree")
    images = []
    with tempfile.TemporaryDirectory() as folder:
        try:
            scene.render.resolution_x, scene.render.resolution_y = noisy.shape[1], noisy.shape[0]
            scene.render.resolution_percentage = 100
            scene.compositing_node_group = tree
            node = tree.nodes.new("CompositorNodeDenoise")
            for socket, pixels in (("Image", noisy), ("Albedo", albedo), ("Normal", normal)):
                if pixels is None:
                    continue
                images.append(_image(socket, pixels, socket == "Normal"))
                source = tree.nodes.new("CompositorNodeImage")
                source.image = images[-1]
                tree.links.new(source.outputs["Image"], node.inputs[socket])
            node.inputs["HDR"].default_value = True
            node.inputs["Prefilter"].default_value = prefilter
            node.inputs["Quality"].default_value = quality
            out = tree.nodes.new("CompositorNodeOutputFile")
            out.directory = folder
            out.file_name = "dn"
            out.save_as_render = False
            out.format.media_type = "MULTI_LAYER_IMAGE"
            out.format.file_format = "OPEN_EXR_MULTILAYER"
            out.format.color_depth = "32"
            out.file_output_items.new("RGBA", "D")
            tree.links.new(node.outputs["Image"], out.inputs["D"])
            assert bpy.ops.render.render(scene=scene.name) == {"FINISHED"}
            (written,) = Path(folder).glob("*.exr")
            exr = OpenEXR.File(str(written), separate_channels=True)
            channels = {k: c.pixels for p in exr.parts for k, c in p.channels.items()}
            return np.stack([channels[f"D.{c}"] for c in "RGB"], -1)
        finally:
            bpy.data.scenes.remove(scene)
            bpy.data.node_groups.remove(tree)
            for image in images:
                bpy.data.images.remove(image)


@pytest.fixture
def oidn():
    """``oidn(noisy, albedo, normal, prefilter, quality)``: the Denoise node's output."""
    return _oidn


def _delivered(noisy, albedo, normal, mask, sigma, prefilter, quality):
    """The node's output on ``noisy`` for the post's pixels (``mask``), and on ``noisy``
    with those pixels times ``max(1 + sigma·g, 0)`` for every other pixel: ``g`` one
    standard normal per pixel, ``numpy.random.default_rng(0)`` over the frame's rows.
    ``sigma`` 0 (or a mask of every pixel or none): the node's output on ``noisy``."""
    mask = np.asarray(mask, dtype=bool)
    first = _oidn(noisy, albedo, normal, prefilter, quality)
    if sigma == 0 or not mask.any() or mask.all():
        return first
    g = np.random.default_rng(0).standard_normal(mask.shape).astype(np.float32)
    stand_in = np.array(noisy[..., :3], dtype=np.float32, copy=True)
    stand_in[mask] *= np.maximum(1.0 + np.float32(sigma) * g[mask], 0.0)[:, None]
    second = _oidn(stand_in, albedo, normal, prefilter, quality)
    return np.where(mask[..., None], first, second)


@pytest.fixture
def delivered_denoise():
    """``delivered_denoise(noisy, albedo, normal, mask, sigma, prefilter, quality)``: a
    whole finished frame denoised as Apply on Render and ``cvsss render`` deliver it, with
    stand-in noise ``sigma``, from the Denoise node's outputs."""
    return _delivered


# -- the extension as users get it -------------------------------------------------------
def _blender_ext() -> Path:
    """Blender's extension tool inside the bpy package (runs under plain Python)."""
    import importlib.util

    (base,) = importlib.util.find_spec("bpy").submodule_search_locations
    (tool,) = Path(base).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py")
    return tool


def _fetch_wheels(manifest: dict) -> None:
    """Download the wheels the manifest lists, as `make wheels` does."""
    for wheel in manifest.get("wheels", []):
        path = ROOT / wheel
        if path.is_file():
            continue
        name, version, python, _abi, platforms = path.stem.split("-")
        platform = platforms.split(".")[0]  # pip takes one tag of a compound one
        subprocess.run(
            [
                sys.executable,
                "-m",
                "pip",
                "download",
                "--quiet",
                f"{name}=={version}",
                "--only-binary=:all:",
                "--no-deps",
                "--python-version",
                python[2] + "." + python[3:],
                "--platform",
                platform,
                "--dest",
                str(path.parent),
            ],
            check=True,
            timeout=600,
        )
        assert path.is_file(), f"pip did not fetch {path.name}"


@pytest.fixture(scope="session")
def extension_zip(tmp_path_factory):
    """The Linux x64 zip built with Blender's extension tool (same commands as `make extension`:
    one zip per platform, each validated)."""
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    _fetch_wheels(manifest)
    out = tmp_path_factory.mktemp("dist")
    tool = _blender_ext()
    build = subprocess.run(
        [
            sys.executable,
            str(tool),
            "build",
            "--split-platforms",
            "--source-dir",
            str(ROOT),
            "--output-dir",
            str(out),
        ],
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )
    assert build.returncode == 0, build.stdout + build.stderr
    platforms = [p.replace("-", "_") for p in manifest["platforms"]]
    zips = sorted(out.glob("*.zip"))
    assert [z.name for z in zips] == sorted(
        f"cvsss-{manifest['version']}-{p}.zip" for p in platforms
    )
    for path in zips:
        check = subprocess.run(
            [sys.executable, str(tool), "validate", str(path)],
            capture_output=True,
            text=True,
            check=False,
            timeout=300,
        )
        assert check.returncode == 0, check.stdout + check.stderr
    return out / f"cvsss-{manifest['version']}-linux_x64.zip"
