"""Which whole parts Cycles renders: the sizes, in mean free paths or d of the
part's own material, below which (or within which) an object's subsurface is left
to Cycles (:mod:`.thin_parts` applies them).

Kept apart from :mod:`.thin_parts`, which needs bpy, so that the command line's
help (:mod:`sss_addon.cli.parser`) and the panel's (:mod:`.properties`) state the
same sizes the rule uses without importing Blender.
"""

from __future__ import annotations

#: An object whose smallest dimension is under this many mean free paths of its Random
#: Walk material is left to Cycles whole: on every part this thin that was measured (the
#: demo's marble tops, apples, candles, block and Suzanne, Blender's default cube made
#: 15-50 across) Cycles' walk with its denoiser at 16 spp came out as close to the ground
#: truth as the post or closer, the walk's light reaching the part's hidden sides, which
#: the post does not see; on thicker ones (75 and more across) the post came out 2-9 dB
#: closer (docs/explanation/accuracy.md §2.3).
THIN_OBJECT_MEAN_FREE_PATHS = 50.0
#: A Christensen-Burley object whose smallest dimension lies in this range of its
#: material's longest d goes to Cycles whole: every part this size measured (the demo's
#: apples at 12-15 d, marble block and Suzanne at 18-20 d, Blender's default cube made
#: 8.4-40 d across) came out closer to the ground truth from Cycles' disk probes with
#: its denoiser than from the post, by up to 2 dB (the apples at 320×180 and at 64 spp;
#: at 128×72 and 16 spp the post had them 0.08 dB closer), the light of the part's
#: hidden faces (a lit top above the face the camera sees) reaching through it; thicker
#: parts (the torus of 75 d, the cube of 100 d and more) came out as close or closer
#: from the post. Below 8 d across the post came out closer on the demo's candles and
#: marble tops (2-7 d across, each long one way or two), but an object under the range's
#: lower end every way (its largest dimension too) goes to Cycles whole as well: on
#: Blender's cube made 1, 2, 3 and 5 d across the post came out 3-8 dB further from the
#: ground truth than Cycles, its light crossing the cube from every hidden face
#: (docs/explanation/accuracy.md §2.3).
BURLEY_OBJECT_D = (8.0, 50.0)


def burley_sizes_text() -> str:
    """The Christensen-Burley sizes :data:`BURLEY_OBJECT_D` sends to Cycles whole, in
    words: "8 to 50 d across or under 8 d every way"."""
    low, high = BURLEY_OBJECT_D
    return f"{low:g} to {high:g} d across or under {low:g} d every way"


def whole_parts_text() -> str:
    """The parts :data:`THIN_OBJECT_MEAN_FREE_PATHS` and :data:`BURLEY_OBJECT_D` send to
    Cycles whole, in words, for help texts: "thinner than 50 mean free paths of their
    Random Walk material, or 8 to 50 d across or under 8 d every way for their
    Christensen-Burley one"."""
    return (
        f"thinner than {THIN_OBJECT_MEAN_FREE_PATHS:g} mean free paths of their Random Walk "
        f"material, or {burley_sizes_text()} for their Christensen-Burley one"
    )
