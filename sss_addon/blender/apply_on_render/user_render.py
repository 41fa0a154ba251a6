"""What the user's render would have made, read before the scene switches to passes.

A render with Apply on Render must give the frame the user had: the passes
the view layer writes (for the compositor and a multilayer EXR) and the
compositor (the denoiser: :func:`..render.job_from_scene`). :func:`user_render`
reads them while the scene still holds the user's settings;
:class:`KeepingPassSetup` is the pass configuration that leaves the user's
passes on beside the add-on's, so that one pass render serves both.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ..passes import PassSetup

#: The Render Layers node's socket of the Combined pass, and the one made of its alpha.
_IMAGE, _ALPHA = "Image", "Alpha"


def user_passes(scene, view_layer) -> list[str]:
    """The passes the scene's engine renders for ``view_layer`` now, Combined first.

    Read from a temporary Render Layers node (its available outputs are the
    passes, named as in a multilayer EXR; Image is Combined, Alpha is part of
    it). It lists every kind the view layer writes: AOVs, light groups,
    Cryptomatte layers, Cycles' denoising and debug passes.
    """
    tree = bpy.data.node_groups.new("cvsss passes", "CompositorNodeTree")
    try:
        node = tree.nodes.new("CompositorNodeRLayers")
        node.scene = scene
        node.layer = view_layer.name
        names = [o.name for o in node.outputs if o.enabled and o.name != _ALPHA]
    finally:
        bpy.data.node_groups.remove(tree)
    return ["Combined" if name == _IMAGE else name for name in names]


def compositing(scene) -> bool:
    """Whether a render of ``scene`` runs its compositor (a node group with nodes)."""
    group = getattr(scene, "compositing_node_group", None)
    return bool(scene.render.use_compositing and group is not None and len(group.nodes))


def multilayer(scene) -> bool:
    """Whether ``scene`` writes multilayer EXRs (every pass of the view layer)."""
    return scene.render.image_settings.file_format == "OPEN_EXR_MULTILAYER"


@dataclass(frozen=True)
class UserRender:
    """What a render of the user's scene makes of one view layer.

    Attributes
    ----------
    passes : list of str
        The view layer's passes (:func:`user_passes`), Combined first.
    compositor : bool
        The scene's compositor runs on the render (:func:`compositing`).
    multilayer : bool
        The output is a multilayer EXR, which holds every pass.
    pass_flags, cycles_flags : frozenset of str
        The view layer's pass switches that are on (``use_pass_*`` of the
        layer and of its Cycles settings), which the pass render keeps on.
    """

    passes: list[str] = field(default_factory=lambda: ["Combined"])
    compositor: bool = False
    multilayer: bool = False
    pass_flags: frozenset[str] = frozenset()
    cycles_flags: frozenset[str] = frozenset()

    @property
    def needs_passes(self) -> bool:
        """Whether the finished frames carry the view layer's passes (to a compositor or a
        multilayer file); otherwise the finished frame alone is delivered."""
        return self.compositor or self.multilayer


def _flags_on(struct, prefixes: tuple[str, ...]) -> frozenset[str]:
    if struct is None:
        return frozenset()
    return frozenset(
        prop.identifier
        for prop in struct.bl_rna.properties
        if prop.type == "BOOLEAN"
        and not prop.is_readonly
        and prop.identifier.startswith(prefixes)
        and getattr(struct, prop.identifier)
    )


def user_render(scene, view_layer) -> UserRender:
    """:class:`UserRender` of ``view_layer`` as the scene is set now (before the switch)."""
    return UserRender(
        passes=user_passes(scene, view_layer),
        compositor=compositing(scene),
        multilayer=multilayer(scene),
        pass_flags=_flags_on(view_layer, ("use_pass_",)),
        cycles_flags=_flags_on(
            getattr(view_layer, "cycles", None), ("use_pass_", "pass_", "denoising_store_passes")
        ),
    )


class KeepingPassSetup(PassSetup):
    """:class:`.passes.PassSetup` that also keeps the user's passes.

    The add-on's own channels are the same as without (the passes are
    independent outputs of the same samples); only the extra passes cost.

    Parameters
    ----------
    scene, materials, view_layer, engine, normal, denoise, guides, thin, thin_points, motion
        As :class:`.passes.PassSetup`.
    user : UserRender or None
        Its pass switches stay on (None: only the add-on's passes).
    """

    def __init__(
        self,
        scene,
        materials,
        view_layer,
        engine: str = "CYCLES",
        normal: bool = False,
        denoise: bool = False,
        user: UserRender | None = None,
        guides: bool = False,
        thin=(),
        thin_points: bool = False,
        motion: bool = True,
    ) -> None:
        super().__init__(
            scene, materials, view_layer, engine, normal, denoise, guides, thin, thin_points, motion
        )
        self.user = user

    def _only_layer(self, wanted) -> None:
        kept = self.user.pass_flags if self.user is not None else frozenset()
        super()._only_layer(lambda ident: wanted(ident) or ident in kept)
        layer = getattr(self.view_layer, "cycles", None)
        if layer is not None and self.user is not None:
            for ident in self.user.cycles_flags:
                setattr(layer, ident, True)

    def index_tables(self) -> dict[str, np.ndarray]:
        """Index passes of the user's to renumber: pass name -> (N,) int table from the
        add-on's number (the Pass Index during the pass render) to the user's.

        Objects get distinct numbers, so Object Index maps back exactly. Materials
        that take no part all get 0: Material Index maps 0 back to their Pass
        Index when they share one (:func:`material_index_exact` tells).
        """
        user = self.user
        tables: dict[str, np.ndarray] = {}
        if user is None:
            return tables
        if "Object Index" in user.passes:
            objects = [o for o in self.scene.objects if o.pass_index > 0]
            table = np.arange(max((o.pass_index for o in objects), default=0) + 1)
            for obj in objects:
                table[obj.pass_index] = self._object_index.get(obj.name, obj.pass_index)
            tables["Object Index"] = table
        if "Material Index" in user.passes:
            copies = self._thin.copies
            table = np.arange(len(self.materials) + len(copies) + 1)
            for slot, material in enumerate(self.materials, 1):
                table[slot] = self._pass_index.get(material.name, slot)
            # A thin object's copy kept the Pass Index of the material it copies.
            for number, name in enumerate(copies, len(self.materials) + 1):
                table[number] = self._pass_index.get(name, 0)
            others = _other_material_indices(self._pass_index, self.materials)
            table[0] = others[0] if len(others) == 1 else 0
            tables["Material Index"] = table
        return tables


def _other_material_indices(saved: dict[str, int], materials) -> list[int]:
    """The distinct Pass Indices (of ``saved``) of the materials not in ``materials``."""
    taking_part = {m.name for m in materials}
    return sorted({index for name, index in saved.items() if name not in taking_part})


def material_index_exact(materials) -> bool:
    """Whether a Material Index pass maps back to the user's numbers exactly: the
    materials that take no part share one Pass Index (0 unless changed)."""
    taking_part = {m.name for m in materials}
    return len({m.pass_index for m in bpy.data.materials if m.name not in taking_part}) <= 1
