"""Rendering the passes the core needs, and putting the scene back afterwards.

:class:`PassSetup` is the one place that changes the user's scene for a pass
render: it snapshots the render settings, the view layers, the material pass
indices and the subsurface weights, applies the pass configuration and
restores every value on exit, also on error and on cancel. Nothing here saves
the .blend.

Passes enabled on the rendered view layer: Combined, Depth (``use_pass_z``),
Material Index, Object Index, Vector (motion blur off; left out where no
method reprojects estimates, see :class:`PassSetup`), Diffuse Direct /
Indirect / Color and optionally Normal; every other pass is switched off.
Denoising, compositing and the sequencer are off; output is a 32-bit
multilayer EXR. For the render, the scene's objects are numbered (their Pass
Index, objects with a participating material first), so the Object Index
pass tells objects apart: Cycles never scatters light from one object into
another, and neither does the post (SSSParams.contact).

EEVEE has no Material Index or Object Index pass (nor Diffuse Indirect: its
Diffuse Light is written as Diffuse Direct): AOV Output nodes added to each
participating material write the labels, and :mod:`.eevee_labels` turns them
into those passes after the render.
"""

from __future__ import annotations

import contextlib
import json
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import bpy

from ...core.camera import Camera
from ...core.frame import MAX_PASS_INDEX, MaterialSpec
from ...core.io.atomic import commit, temp_path
from ...core.io.errors import OutputError
from ...core.io.sidecar import make_sidecar, write_sidecar
from . import materials as sss_materials
from .denoise import denoise_pass_file
from .eevee_labels import AOV_NAME, COVER_AOV, OBJECT_AOV, aov_to_material_index
from .errors import RenderError
from .internal_renders import internal_render
from .thin_parts import (
    THIN_POINT_AOV,
    CyclesRendersThin,
    Thickness,
    thin_point_nodes,
)

# -- generic RNA snapshots -------------------------------------------------------------
_SCALAR_TYPES = {"BOOLEAN", "INT", "FLOAT", "STRING", "ENUM"}


def rna_values(struct, nested: Iterable[str] = ()) -> dict:
    """Writable scalar properties of an RNA struct (and of ``nested`` pointers).

    Returns
    -------
    dict
        identifier -> value (arrays as tuples, enum flags as frozensets);
        ``nested`` pointers as ``{name: dict}`` under their identifier.
    """
    values: dict = {}
    for prop in struct.bl_rna.properties:
        ident = prop.identifier
        if ident == "rna_type" or prop.is_readonly or prop.type not in _SCALAR_TYPES:
            continue
        try:
            value = getattr(struct, ident)
        except (AttributeError, RuntimeError):
            continue
        if prop.type == "ENUM" and prop.is_enum_flag:
            value = frozenset(value)
        elif not isinstance(value, str) and hasattr(value, "__len__"):
            value = tuple(value)
        values[ident] = value
    for name in nested:
        child = getattr(struct, name, None)
        if child is not None:
            values[name] = rna_values(child)
    return values


# Properties whose setting changes others: restored first, in this order.
_FIRST = ("engine", "media_type", "file_format", "color_mode", "color_depth")


def restore_rna(struct, values: dict) -> None:
    """Set every recorded value that differs; pointers recurse.

    One value that cannot be set does not block the others; what still fails
    on the second pass is reported on stderr.
    """
    keys = sorted(values, key=lambda k: _FIRST.index(k) if k in _FIRST else len(_FIRST))
    for attempt in range(2):  # a second pass settles values that depend on one another
        for key in keys:
            value = values[key]
            if isinstance(value, dict):
                child = getattr(struct, key, None)
                if child is not None:
                    restore_rna(child, value)
                continue
            try:
                current = getattr(struct, key)
                if isinstance(value, frozenset):
                    current = frozenset(current)
                elif isinstance(value, tuple):
                    current = tuple(current)
                if current != value:
                    setattr(struct, key, set(value) if isinstance(value, frozenset) else value)
            except (AttributeError, TypeError, ValueError, RuntimeError) as exc:
                if attempt:
                    print(f"cvsss: could not restore {struct!r}.{key}: {exc}", file=sys.stderr)


# -- scene queries ------------------------------------------------------------------------
def render_view_layer(scene, context=None):
    """The view layer whose passes are rendered: the context's, else the first used."""
    if context is not None and getattr(context, "scene", None) == scene:
        layer = getattr(context, "view_layer", None)
        if layer is not None:
            return layer
    for layer in scene.view_layers:
        if layer.use:
            return layer
    return scene.view_layers[0]


def output_size(scene) -> tuple[int, int]:
    """(width, height) in pixels after the resolution percentage, as Blender computes it."""
    r = scene.render
    return (
        r.resolution_x * r.resolution_percentage // 100,
        r.resolution_y * r.resolution_percentage // 100,
    )


def scene_camera(scene) -> Camera:
    """The core's Camera for the scene's active camera at the current frame."""
    obj = scene.camera
    if obj is None or obj.type != "CAMERA":
        raise RenderError(f"scene {scene.name!r} has no active camera")
    cam = obj.data
    if cam.type not in ("PERSP", "ORTHO"):
        raise RenderError(
            f"camera {obj.name!r} is {cam.type}; only perspective and orthographic cameras "
            "are supported"
        )
    width, height = output_size(scene)
    if width <= 0 or height <= 0:
        raise RenderError(
            f"the output is {width}x{height} pixels (Resolution "
            f"{scene.render.resolution_x}x{scene.render.resolution_y} at "
            f"{scene.render.resolution_percentage} %); raise the resolution or its %"
        )
    r = scene.render
    try:
        return Camera(
            width=width,
            height=height,
            type=cam.type,
            lens=float(cam.lens),
            sensor_width=float(cam.sensor_width),
            sensor_height=float(cam.sensor_height),
            sensor_fit=cam.sensor_fit,
            ortho_scale=float(cam.ortho_scale),
            pixel_aspect_x=float(r.pixel_aspect_x),
            pixel_aspect_y=float(r.pixel_aspect_y),
            clip_start=float(cam.clip_start),
            clip_end=float(cam.clip_end),
            shift_x=float(cam.shift_x),
            shift_y=float(cam.shift_y),
        )
    except ValueError as exc:  # a setting the core's camera model refuses
        raise RenderError(f"camera {obj.name!r}: {exc}") from None


def engine_identifier(scene, engine: str) -> str:
    """Blender's identifier for ``CYCLES`` or ``EEVEE`` (BLENDER_EEVEE_NEXT in 4.2–4.4)."""
    if engine not in ("CYCLES", "EEVEE"):
        raise RenderError(f"engine must be CYCLES or EEVEE, got {engine!r}")
    if engine == "CYCLES":
        return "CYCLES"
    items = {i.identifier for i in scene.render.bl_rna.properties["engine"].enum_items}
    return "BLENDER_EEVEE_NEXT" if "BLENDER_EEVEE_NEXT" in items else "BLENDER_EEVEE"


# -- the pass configuration -----------------------------------------------------------------
#: Value AOV that carries a linked (textured) Subsurface Weight per pixel.
WEIGHT_AOV = "cvsss_weight"

#: Version of the pass set this module renders (2: with the Object Index pass; 3: EEVEE's
#: edge pixels labelled by :func:`.eevee_labels.eevee_labels`); the demo renders its
#: passes again when it changes.
PASS_FORMAT = 3

NEEDED_PASSES = (
    "use_pass_combined",
    "use_pass_z",
    "use_pass_material_index",
    "use_pass_object_index",
    "use_pass_vector",
    "use_pass_diffuse_direct",
    "use_pass_diffuse_indirect",
    "use_pass_diffuse_color",
)


class SceneSetup(contextlib.AbstractContextManager):
    """Snapshot ``scene``'s render settings and view layers, change them, restore on exit.

    The one snapshot of what a render changes: ``scene.render`` (with its
    image settings), the Cycles and EEVEE scene settings and every view layer
    (with its Cycles settings) are recorded with :func:`rna_values` on entry
    and put back with :func:`restore_rna` on exit, also on error and on
    cancel. Subclasses make their changes in :meth:`_apply` and extend
    :meth:`restore` for what they change beyond these structs.

    Parameters
    ----------
    scene : bpy.types.Scene
    view_layer : bpy.types.ViewLayer
        The only view layer rendered.
    """

    def __init__(self, scene, view_layer) -> None:
        self.scene = scene
        self.view_layer = view_layer
        self._saved: list[tuple[object, dict]] = []

    def _structs(self) -> Iterator[tuple[object, tuple[str, ...]]]:
        scene = self.scene
        yield scene.render, ("image_settings",)
        for name in ("cycles", "eevee"):
            if getattr(scene, name, None) is not None:
                yield getattr(scene, name), ()
        for layer in scene.view_layers:
            yield layer, ()
            if getattr(layer, "cycles", None) is not None:
                yield layer.cycles, ()

    def __enter__(self):
        try:
            self._saved = [(s, rna_values(s, nested)) for s, nested in self._structs()]
            self._apply()
        except BaseException:
            self.restore()
            raise
        return self

    def _apply(self) -> None:
        raise NotImplementedError

    def _output_exr(self) -> None:
        """Whole frame, no compositing or sequencer, 32-bit multilayer EXR."""
        r = self.scene.render
        r.use_compositing = False
        r.use_sequencer = False
        r.use_border = False  # the post-process needs the whole frame
        r.use_file_extension = True
        r.use_single_layer = False
        s = r.image_settings
        if hasattr(s, "media_type"):
            s.media_type = "MULTI_LAYER_IMAGE"
        s.file_format = "OPEN_EXR_MULTILAYER"
        s.color_depth = "32"
        s.exr_codec = "ZIP"

    def _only_layer(self, wanted: Callable[[str], bool]) -> None:
        """Render only the view layer, with the passes ``wanted(identifier)`` accepts.

        Every Cycles layer flag (passes, denoising, denoising data) is switched off.
        """
        layer = self.view_layer
        for other in self.scene.view_layers:
            other.use = other == layer
        for prop in layer.bl_rna.properties:
            ident = prop.identifier
            if ident.startswith("use_pass_") and not prop.is_readonly:
                setattr(layer, ident, wanted(ident))
        cycles_layer = getattr(layer, "cycles", None)
        if cycles_layer is not None:
            for prop in cycles_layer.bl_rna.properties:
                if (
                    prop.type == "BOOLEAN"
                    and not prop.is_readonly
                    and (
                        prop.identifier.startswith(("use_pass_", "pass_"))
                        or prop.identifier in ("use_denoising", "denoising_store_passes")
                    )
                ):
                    setattr(cycles_layer, prop.identifier, False)

    def restore(self) -> None:
        """Put back every recorded struct (safe to call more than once)."""
        for struct, values in self._saved:
            restore_rna(struct, values)
        self._saved = []

    def __exit__(self, *exc) -> None:
        self.restore()


class PassSetup(SceneSetup):
    """Configure ``scene`` for the pass render of ``materials``; restore on exit.

    Parameters
    ----------
    scene : bpy.types.Scene
    materials : list of bpy.types.Material
        Participating materials; they get pass indices 1..K (in this order)
        and Subsurface Weight 0. Every other material gets pass index 0.
        The scene's objects get pass indices 1..N (:func:`number_objects`).
    view_layer : bpy.types.ViewLayer
        The only view layer rendered.
    engine : {"CYCLES", "EEVEE"}
    normal : bool
        Also enable the Normal pass.
    denoise : bool
        Also write Cycles' Denoising Albedo and Normal passes (the guides of
        :func:`.denoise.denoise_pass_file`, which removes them again).
    guides : bool
        Also write them, to stay in the file: the guides of the finished
        frame's denoise (:mod:`.denoise_frame`).
    thin : list of (bpy.types.Object, list of bpy.types.Material)
        Objects whose subsurface in those materials Cycles renders
        (:class:`.thin_parts.CyclesRendersThin`, entered before anything else
        changes, so the copies keep the materials' subsurface; restored last).
    thin_points : bool
        Cycles also renders the subsurface of the Random Walk materials' thin
        points (:func:`.thin_parts.thin_point_nodes`), and their pixels take no
        part (:func:`core.io.exr.read_frame` reads the AOV that says so).
    motion : bool
        Render the Vector pass (default). Only the temporal methods need it: they
        reuse last frame's estimates, which must be moved with the surface. The
        other methods' history only steers how many samples a pixel takes, which
        changes the noise, and the engine pays for the pass by evaluating the scene
        at the neighbouring frames as well.
    """

    def __init__(
        self,
        scene,
        materials,
        view_layer,
        engine: str = "CYCLES",
        normal: bool = False,
        denoise: bool = False,
        guides: bool = False,
        thin=(),
        thin_points: bool = False,
        motion: bool = True,
    ) -> None:
        super().__init__(scene, view_layer)
        self.motion = motion
        self.materials = list(materials)
        self.engine = engine_identifier(scene, engine)
        self.normal = normal
        self.denoise = denoise
        self.guides = guides
        self._pass_index: dict[str, int] = {}
        self._object_index: dict[str, int] = {}
        self._sss: sss_materials.SSSDisabled | None = None
        self._aov = None
        self._object_aov = None
        self._cover_aov = None
        self._weight_aov = None
        self._thin_aov = None
        self._thickness: Thickness | None = None
        self.thin_points = thin_points
        self._aov_nodes: list[tuple[object, str]] = []
        self._thin = CyclesRendersThin(thin)

    def __enter__(self) -> PassSetup:
        try:
            self._thin.__enter__()
            self._pass_index = pass_indices(bpy.data.materials)
            self._object_index = pass_indices(bpy.data.objects)
            super().__enter__()
            self._sss = sss_materials.SSSDisabled(self.materials).__enter__()
            if self.thin_points and self.engine == "CYCLES":
                self._add_thin_points()
        except BaseException:
            self.restore()
            raise
        return self

    def _apply(self) -> None:
        scene = self.scene
        r = scene.render
        if r.engine != self.engine:  # the update tells every viewport: only when it changes
            r.engine = self.engine
        r.use_motion_blur = False  # the Vector pass is not written with motion blur
        self._output_exr()
        if getattr(scene, "cycles", None) is not None:
            scene.cycles.use_denoising = False
        needed = set(NEEDED_PASSES) - (set() if self.motion else {"use_pass_vector"})
        self._only_layer(
            lambda ident: ident in needed or (self.normal and ident == "use_pass_normal")
        )
        # Cycles' guide passes: another engine writes none (EEVEE's finished frames are
        # denoised without guides, denoise_frame.EEVEE_DENOISE).
        if (self.denoise or self.guides) and self.engine == "CYCLES":
            self.view_layer.cycles.denoising_store_passes = True
        for material in bpy.data.materials:
            if material.pass_index != 0 and material.is_editable:
                material.pass_index = 0
        for slot, material in enumerate(self.materials, 1):
            material.pass_index = slot
        # Thin objects' copies take no part; numbered past the table (the pass reader
        # reads such a number as 0), so the user's Material Index is found again for
        # their pixels (apply_on_render.user_render).
        for number, name in enumerate(self._thin.copies, len(self.materials) + 1):
            bpy.data.materials[name].pass_index = number
        number_objects(self.scene, self.materials)
        if self.engine != "CYCLES":
            self._add_material_aov()
        self._add_weight_aovs()

    def _add_weight_aovs(self) -> None:
        """Write each linked Subsurface Weight to the value AOV ``cvsss_weight``.

        Runs before the weights are forced to 0, while their links still
        exist; the core reads the AOV on those materials' pixels. A node group
        shared by several materials gets one AOV output: Cycles adds up the
        AOV outputs a shader evaluates, so a second one would double the weight.
        """
        done = set()
        for material in self.materials:
            source = sss_materials.weight_source(material)
            if source is None:
                continue
            tree, from_socket = source
            if tree.as_pointer() in done:
                continue
            done.add(tree.as_pointer())
            self._layer_aov(WEIGHT_AOV, "_weight_aov", "VALUE")
            node = self._new_node(tree, "ShaderNodeOutputAOV")
            node.aov_name = WEIGHT_AOV
            tree.links.new(from_socket, node.inputs["Value"])

    def _add_thin_points(self) -> None:
        """The value AOV of thin points, and the nodes that keep their subsurface on."""
        self._layer_aov(THIN_POINT_AOV, "_thin_aov", "VALUE")
        self._thickness = Thickness(self.materials).__enter__()
        for material in self.materials:
            thin_point_nodes(material, self._new_node)

    def _layer_aov(self, name: str, attr: str, kind: str) -> None:
        """Give the view layer the AOV ``name`` of ``kind`` ("VALUE", "COLOR") unless it
        has one; the one added is kept in ``attr``, which :meth:`restore` removes."""
        layer = self.view_layer
        if not any(aov.name == name for aov in layer.aovs):
            aov = layer.aovs.add()
            aov.name = name
            aov.type = kind
            setattr(self, attr, aov)

    def _new_node(self, tree, kind: str):
        """A new node of ``kind`` in ``tree``, which :meth:`restore` removes."""
        node = tree.nodes.new(kind)
        self._aov_nodes.append((tree, node.name))
        return node

    def _add_material_aov(self) -> None:
        """EEVEE: write each material's slot to the value AOV ``cvsss_material``, its
        object's Pass Index to ``cvsss_object`` and (1, slot², index²) to the colour
        AOV ``cvsss_cover`` (:mod:`.eevee_labels`)."""
        self._layer_aov(AOV_NAME, "_aov", "VALUE")
        self._layer_aov(OBJECT_AOV, "_object_aov", "VALUE")
        self._layer_aov(COVER_AOV, "_cover_aov", "COLOR")
        new = self._new_node
        for slot, material in enumerate(self.materials, 1):
            tree = material.node_tree
            node = new(tree, "ShaderNodeOutputAOV")
            node.aov_name = AOV_NAME
            node.inputs["Value"].default_value = float(slot)
            info = new(tree, "ShaderNodeObjectInfo")
            node = new(tree, "ShaderNodeOutputAOV")
            node.aov_name = OBJECT_AOV
            tree.links.new(info.outputs["Object Index"], node.inputs["Value"])
            square = new(tree, "ShaderNodeMath")
            square.operation = "MULTIPLY"
            tree.links.new(info.outputs["Object Index"], square.inputs[0])
            tree.links.new(info.outputs["Object Index"], square.inputs[1])
            combine = new(tree, "ShaderNodeCombineColor")
            combine.mode = "RGB"
            combine.inputs["Red"].default_value = 1.0
            combine.inputs["Green"].default_value = float(slot * slot)
            tree.links.new(square.outputs["Value"], combine.inputs["Blue"])
            node = new(tree, "ShaderNodeOutputAOV")
            node.aov_name = COVER_AOV
            tree.links.new(combine.outputs["Color"], node.inputs["Color"])

    def restore(self) -> None:
        """Put back everything saved so far (safe to call more than once)."""
        for tree, name in reversed(self._aov_nodes):
            node = tree.nodes.get(name)
            if node is not None:
                tree.nodes.remove(node)
        self._aov_nodes = []
        for name in ("_aov", "_object_aov", "_cover_aov", "_weight_aov", "_thin_aov"):
            aov = getattr(self, name)
            if aov is not None:
                self.view_layer.aovs.remove(aov)
                setattr(self, name, None)
        if self._thickness is not None:
            self._thickness.restore()
            self._thickness = None
        if self._sss is not None:
            self._sss.restore()
            self._sss = None
        put_back_pass_indices(bpy.data.materials, self._pass_index)
        self._pass_index = {}
        put_back_pass_indices(bpy.data.objects, self._object_index)
        self._object_index = {}
        try:
            super().restore()
        finally:
            self._thin.restore()


def pass_indices(datablocks) -> dict[str, int]:
    """name -> Pass Index of every material or object (what :class:`PassSetup` restores)."""
    return {d.name: d.pass_index for d in datablocks}


def put_back_pass_indices(datablocks, saved: dict[str, int]) -> None:
    """Set each datablock's Pass Index back to ``saved`` where it changed."""
    for d in datablocks:
        index = saved.get(d.name)
        if index is not None and d.pass_index != index:
            d.pass_index = index


def number_objects(scene, materials) -> None:
    """Give the scene's objects distinct Pass Indices (1, 2, …) for the Object Index pass.

    Objects that carry one of ``materials`` come first, so they stay distinct
    even in a scene with more objects than Blender numbers (32767); the rest
    share 0 from there on (they are not scattered from, only told apart from
    the ones that are). Linked (read-only) objects keep theirs.
    :class:`PassSetup` restores them all.
    """
    wanted = set(materials)
    in_scene = [o for o in scene.objects if o.is_editable]
    # Stable: the carriers first, each part in the scene's order.
    order = sorted(in_scene, key=lambda o: not sss_materials.carries(o, wanted))
    numbers = {o.name: i for i, o in enumerate(order, 1) if i <= MAX_PASS_INDEX}
    for obj in in_scene:
        index = numbers.get(obj.name, 0)
        if obj.pass_index != index:
            obj.pass_index = index


# -- one frame ---------------------------------------------------------------------------------
def pass_path(passes_dir: Path, frame: int) -> Path:
    """``<passes_dir>/####.exr`` for ``frame``."""
    return Path(passes_dir) / f"{frame:04d}.exr"


def read_record(path: Path) -> dict | None:
    """The JSON object at ``path``, or None when it is missing or unreadable."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def frame_done(passes_dir: Path, frame: int, denoised: bool = False, guides: bool = False) -> bool:
    """The pass EXR and its sidecar of ``frame`` both exist, made with ``denoised`` as asked
    and, with ``guides``, holding the guides of the finished frame's denoise.

    A sidecar without ``"denoised"`` records undenoised passes, one without
    ``"denoise"`` passes without the guides; an unreadable sidecar counts as
    missing (the frame is rendered again).
    """
    path = pass_path(passes_dir, frame)
    if not (path.is_file() and path.with_suffix(".json").is_file()):
        return False
    record = read_record(path.with_suffix(".json"))
    if record is None or bool(record.get("denoised", False)) != denoised:
        return False
    return not guides or isinstance(record.get("denoise"), dict)


def pass_changes(passes_dir: Path, frame: int, sidecar: dict) -> list[str]:
    """The fields of ``frame``'s existing pass sidecar that differ from ``sidecar``.

    ``sidecar`` is what a render of the frame would write now
    (:func:`pass_sidecar`, the scene at the frame): another resolution,
    camera, material, Subsurface Weight, unit scale, view layer or engine
    makes the existing passes stale, and so does another set of objects whose subsurface
    Cycles rendered. The ``denoised`` flag and the
    ``denoise`` record are :func:`frame_done`'s. Empty when they agree (or
    nothing exists).
    """
    have = read_record(pass_path(passes_dir, frame).with_suffix(".json"))
    if have is None:
        return []
    have = {k: v for k, v in have.items() if k not in ("denoised", "denoise")}
    want = json.loads(json.dumps(sidecar))  # tuples as lists, as read back
    return sorted(k for k in set(want) | set(have) if want.get(k) != have.get(k))


def _render_still(scene) -> None:
    """Render the current frame and write ``scene.render.filepath`` (tests replace this)."""
    with internal_render():
        result = bpy.ops.render.render(write_still=True, scene=scene.name)
    if "FINISHED" not in result:
        raise RenderError(f"rendering frame {scene.frame_current} was cancelled")


def fresh_cycles_state(scene) -> None:
    """Make Cycles rebuild its scene for the next render (a crash workaround).

    Alternating renders with Subsurface Weight forced to 0 (the passes) and
    with subsurface on (the ground truth) in one process makes Cycles 5.0.1
    crash in its surface integrator within a few dozen renders (reproduced:
    every run of 18 alternations, with either subsurface method). Switching
    the engine away and back drops Cycles' cached state; with it, 2 × 45
    alternations ran clean. Only Cycles renders need it.
    """
    r = scene.render
    if r.engine == "CYCLES":
        r.engine = "BLENDER_WORKBENCH"
        r.engine = "CYCLES"


def render_to(scene, path: Path, finish: Callable[[Path], None] | None = None) -> None:
    """Render the current frame to ``path`` atomically (scene already set up).

    Blender renders to a temporary name beside ``path`` (keeping the
    extension, from which it picks the format), ``finish(temp)`` may rewrite
    that file, and it is renamed into place: ``path`` is complete or absent.
    """
    temp = temp_path(path, keep_suffix=True)
    scene.render.filepath = str(temp)
    fresh_cycles_state(scene)
    try:
        _render_still(scene)
        if not temp.is_file():
            raise OutputError(temp, "Blender wrote no file (check the output folder)")
        if finish is not None:
            finish(temp)
        commit(temp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            temp.unlink()


def render_frame(
    scene,
    frame: int,
    passes_dir: Path,
    specs: list[MaterialSpec],
    view_layer,
    denoise: bool = False,
    finished_denoise: dict | None = None,
    thin: dict | None = None,
) -> Path:
    """Render the passes of ``frame`` (scene already set up) to ``####.exr`` + sidecar.

    The sidecar is written first and the EXR rendered to a temporary name
    that is renamed into place, so a pass file is complete or absent. An
    older EXR of the frame is removed before its sidecar is replaced, so a
    failed render never leaves a file the new sidecar does not describe.
    With ``denoise`` the passes the post reads are denoised
    (:func:`.denoise.denoise_pass_file`) before the rename, and the sidecar
    records ``"denoised": true``. ``finished_denoise`` (the scene's denoiser
    settings, :meth:`.denoise_frame.DenoiseSettings.to_dict`; the scene set up
    with ``guides``) is recorded as ``"denoise"``: the file keeps the guides,
    and the finished frames made of it are to be denoised so. ``thin`` as
    :func:`pass_sidecar`.

    Returns
    -------
    Path of the pass EXR.
    """
    scene.frame_set(frame)
    path = pass_path(passes_dir, frame)
    sidecar = pass_sidecar(scene, frame, specs, view_layer, thin)
    if denoise:
        sidecar["denoised"] = True
    if finished_denoise is not None:
        sidecar["denoise"] = dict(finished_denoise)
    try:
        path.unlink()
    except FileNotFoundError:
        pass
    except OSError as exc:  # a folder in its place, no permission
        raise OutputError(path, exc) from None
    write_sidecar(path.with_suffix(".json"), sidecar, overwrite=True)

    render_to(scene, path, lambda temp: finish_pass_file(temp, scene, view_layer, sidecar, denoise))
    return path


def pass_sidecar(
    scene, frame: int, specs: list[MaterialSpec], view_layer, thin: dict | None = None
) -> dict:
    """The sidecar of ``frame``'s pass EXR: the camera now (scene at the frame) and ``specs``;
    ``thin``, what of the thin parts Cycles rendered (:func:`.thin_parts.record`), when it
    renders any (passes made with another choice are stale, :func:`pass_changes`)."""
    sidecar = make_sidecar(
        scene_camera(scene),
        specs,
        frame=frame,
        view_layer=view_layer.name,
        engine=scene.render.engine,
        scene_unit_scale=float(scene.unit_settings.scale_length) or 1.0,
    )
    if thin:
        sidecar["thin_parts"] = thin
    return sidecar


def finish_pass_file(path: Path, scene, view_layer, sidecar: dict, denoise: bool) -> None:
    """What follows Blender's write of a pass EXR: EEVEE's AOV becomes the Material
    Index pass, and with ``denoise`` the passes the post reads are denoised. (Cycles'
    pixels of thin points stay as written: the reader takes them out of the post.)"""
    if scene.render.engine != "CYCLES":
        aov_to_material_index(path, view_layer.name, sidecar["camera"]["clip_end"])
    if denoise:
        denoise_pass_file(path, view_layer.name, scene.cycles.samples)
