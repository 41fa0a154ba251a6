"""The user's compositor on the finished frames.

Finished frames are delivered by rendering the *output scene* (a copy of the
user's, :func:`.scenes.output_scene`) with :class:`.engine.ResultEngine`.
Blender runs the output scene's compositor on that render, so the output
scene gets a copy of the user's compositor node group whose Render Layers
nodes (and Cryptomatte nodes reading the render) read the output scene
instead of the user's (:func:`retarget`): their Image is the finished frame,
their other sockets the passes the engine declares. Nested node groups that
hold such nodes are copied too; the others are shared. A still delivered on
the user's scene itself (:class:`.scenes.DisplaySetup`) needs no copy.

:func:`refresh_render_layers` makes the Render Layers nodes offer the
sockets of the passes declared now: a link from a socket that is not
available is skipped by the compositor (its input gets nothing).
"""

from __future__ import annotations

import contextlib

import bpy

RENDER_LAYERS = "CompositorNodeRLayers"
CRYPTOMATTE = "CompositorNodeCryptomatteV2"
GROUP = "CompositorNodeGroup"


def _reads_render(node, scene) -> bool:
    """Whether ``node`` reads ``scene``'s render: Render Layers, Cryptomatte (Render)."""
    if node.bl_idname == RENDER_LAYERS or (
        node.bl_idname == CRYPTOMATTE and node.source == "RENDER"
    ):
        return node.scene in (None, scene)
    return False


def _walk(tree, seen: set[int]):
    """Every node of ``tree`` and of the groups nested in it (each group once)."""
    if tree is None or tree.as_pointer() in seen:
        return
    seen.add(tree.as_pointer())
    for node in tree.nodes:
        yield node
        if node.bl_idname == GROUP:
            yield from _walk(node.node_tree, seen)


def reads_render(tree, scene) -> bool:
    """Whether ``tree`` (or a group nested in it) reads ``scene``'s render."""
    return any(_reads_render(node, scene) for node in _walk(tree, set()))


def render_layer_names(tree, scene) -> set[str]:
    """The view layers of ``scene`` that the Render Layers nodes of ``tree`` read."""
    return {
        node.layer
        for node in _walk(tree, set())
        if node.bl_idname == RENDER_LAYERS and node.scene in (None, scene)
    }


def retarget(tree, scene, out, made: list, copies: dict | None = None):
    """A copy of compositor node group ``tree`` whose nodes that read ``scene``'s render
    read ``out``'s (also in nested groups, which are copied where they hold one).

    Every copy is appended to ``made``; :func:`remove` removes them.
    """
    copies = {} if copies is None else copies
    key = tree.as_pointer()
    if key in copies:
        return copies[key]
    copy = tree.copy()
    copy.name = f"cvsss output ({tree.name})"
    made.append(copy)
    copies[key] = copy
    for node in copy.nodes:
        if _reads_render(node, scene):
            attr = "layer" if node.bl_idname == RENDER_LAYERS else "layer_name"
            layer = getattr(node, attr)
            node.scene = out
            with contextlib.suppress(TypeError):  # a layer name the scene no longer has
                setattr(node, attr, layer)
        elif node.bl_idname == GROUP and reads_render(node.node_tree, scene):
            node.node_tree = retarget(node.node_tree, scene, out, made, copies)
    return copy


def refresh_render_layers(scene) -> None:
    """Make the Render Layers nodes that read ``scene`` offer the sockets of the passes
    its engine declares now.

    ``ViewLayer.update_render_passes`` updates the nodes of the scene's own
    node group; assigning a node's scene updates that node, also in a nested
    group.
    """
    for view_layer in scene.view_layers:
        view_layer.update_render_passes()
    for node in _walk(getattr(scene, "compositing_node_group", None), set()):
        if node.bl_idname == RENDER_LAYERS and node.scene == scene:
            layer = node.layer
            node.scene = scene
            with contextlib.suppress(TypeError):
                node.layer = layer


def remove(made: list) -> None:
    """Remove the node groups :func:`retarget` made (safe to call twice)."""
    for group in reversed(made):
        with contextlib.suppress(ReferenceError, RuntimeError):
            bpy.data.node_groups.remove(group)
    made.clear()
