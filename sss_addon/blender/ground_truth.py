"""Ground truth: the same frame path-traced by Cycles with its own subsurface on.

The ground truth (docs/explanation/accuracy.md §1): each (or every k-th) frame is rendered again by
Cycles — also when the passes are rendered with EEVEE — with subsurface on,
with the user's Subsurface Weight, Radius and Scale. By default (MATERIAL)
every Principled BSDF keeps its own ``subsurface_method`` — Christensen-Burley,
Random Walk or Random Walk (Skin), each of which the post models; BURLEY or
RANDOM_WALK force that method on every Principled BSDF of the participating
materials (also inside node groups). Denoising, adaptive sampling, the time limit and
sample subsets are off, the seed fixed (:data:`SEED`), so every pixel gets
exactly ``samples`` paths. Resolution, camera, border and pixel filter are
the passes' (motion blur off in both).

Layout under the output folder::

    ground_truth/####.exr   multilayer EXR holding <layer>.Combined (read it with
                            core.io.exr.read_combined)
    ground_truth/####.json  how it was made: method, samples, seed (a frame made
                            otherwise is rendered again)

:class:`GroundTruthSetup` changes the scene through the snapshot of
:class:`.passes.SceneSetup` and puts every value back on exit, also on
error and on cancel.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

from ...core.io.atomic import write_text
from . import materials as sss_materials
from .passes import SceneSetup, read_record, render_to, restore_rna

#: The ground truth's subsurface method: each material's own (MATERIAL), or one forced on
#: all (Blender identifiers).
METHODS = ("MATERIAL", "BURLEY", "RANDOM_WALK")

#: Default samples per pixel (docs/explanation/accuracy.md: at least 1024).
DEFAULT_SAMPLES = 1024

#: Cycles' hard limit on samples per pixel.
MAX_SAMPLES = 2**24

#: Cycles seed of every ground-truth render.
SEED = 0

#: Value of the ``format`` field of the ``####.json`` record.
RECORD_FORMAT = "cvsss-ground-truth/1"


class GroundTruthSetup(SceneSetup):
    """Configure ``scene`` for the ground-truth render; restore on exit.

    Parameters
    ----------
    scene : bpy.types.Scene
    materials : list of bpy.types.Material
        Participating materials: their Principled BSDFs get ``method``.
    view_layer : bpy.types.ViewLayer
        The only view layer rendered (Combined pass only).
    samples : int, samples per pixel, 1 … :data:`MAX_SAMPLES`
    method : {"MATERIAL", "BURLEY", "RANDOM_WALK"}
        MATERIAL leaves every node's own method.
    denoise : bool
        Denoise with Cycles' OpenImageDenoise (albedo and normal guides): not
        a ground truth, the equal-time comparison's "Cycles + OIDN".
    """

    def __init__(
        self,
        scene,
        materials,
        view_layer,
        samples: int = DEFAULT_SAMPLES,
        method: str = "MATERIAL",
        denoise: bool = False,
    ) -> None:
        super().__init__(scene, view_layer)
        self.materials = list(materials)
        self.samples = int(samples)
        self.method = method
        self.denoise = bool(denoise)
        self._nodes: list[tuple[object, dict]] = []

    def _apply(self) -> None:
        scene = self.scene
        r = scene.render
        r.engine = "CYCLES"
        r.use_motion_blur = False  # as in the passes the composite is made of
        self._output_exr()
        c = scene.cycles
        c.samples = self.samples
        c.use_adaptive_sampling = False
        c.time_limit = 0.0
        for name in ("use_sample_subset", "sample_offset"):  # not in every 4.x
            if hasattr(c, name):
                setattr(c, name, type(getattr(c, name))(0))
        c.seed = SEED
        c.use_animated_seed = False
        c.use_denoising = self.denoise
        if self.denoise:
            c.denoiser = "OPENIMAGEDENOISE"
            c.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        self._only_layer(lambda ident: ident == "use_pass_combined")
        if self.denoise and getattr(self.view_layer, "cycles", None) is not None:
            self.view_layer.cycles.use_denoising = True
        if self.method == "MATERIAL":
            return
        seen = set()
        for material in self.materials:
            for _, node in sss_materials.principled_nodes(material.node_tree):
                if node.as_pointer() in seen:  # a node group shared by two materials
                    continue
                seen.add(node.as_pointer())
                self._nodes.append((node, {"subsurface_method": node.subsurface_method}))
                node.subsurface_method = self.method

    def restore(self) -> None:
        """Put back the subsurface methods and the render settings (safe to call twice)."""
        for node, values in reversed(self._nodes):
            restore_rna(node, values)
        self._nodes = []
        super().restore()


def ground_truth_path(folder: Path, frame: int) -> Path:
    """``<folder>/####.exr`` for ``frame``."""
    return Path(folder) / f"{frame:04d}.exr"


def material_methods(materials) -> dict[str, list[str]]:
    """Material name -> the ``subsurface_method`` of each of its Principled BSDFs (a
    MATERIAL ground truth renders these)."""
    return {
        material.name: [
            str(node.subsurface_method)
            for _, node in sss_materials.principled_nodes(material.node_tree)
        ]
        for material in materials
    }


def _record(
    frame: int,
    samples: int,
    method: str,
    view_layer: str,
    denoise: bool = False,
    materials=(),
) -> dict:
    record = {
        "format": RECORD_FORMAT,
        "frame": int(frame),
        "engine": "CYCLES",
        "subsurface_method": method,
        "samples": int(samples),
        "seed": SEED,
        "denoised": bool(denoise),
        "view_layer": view_layer,
    }
    if method == "MATERIAL":
        record["material_methods"] = material_methods(materials)
    return record


def ground_truth_done(folder: Path, frame: int, samples: int, method: str, materials=()) -> bool:
    """The frame's ground truth exists and was made with ``samples`` and ``method`` (for
    MATERIAL: with the methods ``materials`` have now)."""
    path = ground_truth_path(folder, frame)
    record = read_record(path.with_suffix(".json"))
    return (
        path.is_file()
        and record is not None
        and record.get("format") == RECORD_FORMAT
        and (record.get("subsurface_method"), record.get("samples"), record.get("seed"))
        == (method, int(samples), SEED)
        and (method != "MATERIAL" or record.get("material_methods") == material_methods(materials))
    )


def render_ground_truth(
    scene,
    frame: int,
    folder: Path,
    materials,
    view_layer,
    samples: int = DEFAULT_SAMPLES,
    method: str = "MATERIAL",
    denoise: bool = False,
) -> Path:
    """Render the ground truth of ``frame`` to ``<folder>/####.exr`` (+ ``.json``).

    ``denoise`` renders Cycles + OIDN instead (the equal-time comparison).

    The record is written first and the EXR rendered to a temporary name
    that is renamed into place (an older EXR is removed before), so the
    ground truth of a frame is complete and described by its record, or absent.

    Returns
    -------
    Path of the ground-truth EXR.
    """
    path = ground_truth_path(folder, frame)
    scene.frame_set(frame)
    with GroundTruthSetup(scene, materials, view_layer, samples, method, denoise):
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        record = _record(frame, samples, method, view_layer.name, denoise, materials)
        write_text(path.with_suffix(".json"), json.dumps(record, indent=2) + "\n")
        render_to(scene, path)
    return path
