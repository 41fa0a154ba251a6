"""EEVEE's labels: the Material and Object Index passes an EEVEE pass render lacks.

EEVEE has no Material Index or Object Index pass. For EEVEE,
:class:`.passes.PassSetup` adds AOV Output nodes to each participating
material: the value AOVs :data:`AOV_NAME` (the material's slot) and
:data:`OBJECT_AOV` (the object's number, from an Object Info node), and the
colour AOV :data:`COVER_AOV` (1, slot², object number²). After the render,
:func:`aov_to_material_index` rewrites the EXR so that they become the
``Material Index`` and ``Object Index`` passes, and the background depth,
which EEVEE writes as the clip end, becomes 1e10 as in Cycles.

EEVEE filters AOVs like colours, so an edge pixel holds a weighted mean of
the labels of the surfaces it covers; :func:`eevee_labels` reads one
surface's labels out of that mix, as Cycles would label the pixel.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...core.io.errors import OutputError
from ...core.io.exr import BACKGROUND_DEPTH_WRITTEN
from .exr_rewrite import rewrite_exr

#: Value AOV that carries the material slot when the engine has no Material Index pass.
AOV_NAME = "cvsss_material"

#: Value AOV that carries the object's number when the engine has no Object Index pass.
OBJECT_AOV = "cvsss_object"

#: Colour AOV (1, slot², object number²) on participating materials: with it, a pixel
#: EEVEE's filter mixed from several surfaces is told from one surface's
#: (:func:`eevee_labels`).
COVER_AOV = "cvsss_cover"


def aov_to_material_index(path: Path, layer: str, clip_end: float) -> None:
    """Rewrite an EEVEE pass EXR in place so it reads like a Cycles one.

    The value AOVs ``<layer>.cvsss_material`` and ``<layer>.cvsss_object`` become
    ``<layer>.Material Index`` and ``<layer>.Object Index`` (:func:`eevee_labels`),
    ``<layer>.cvsss_cover`` is dropped and depths at the clip end become 1e10.
    """
    aovs = {f"{layer}.{n}": n for n in (AOV_NAME, OBJECT_AOV, COVER_AOV)}
    labels = {}

    def prepare(parts: dict) -> None:
        read = {}
        for name, channels in parts.items():
            if aovs.get(name) == COVER_AOV:
                read[COVER_AOV] = [channels[f"{name}.{c}"] for c in "RGB"]
            elif name in aovs:
                (read[aovs[name]],) = channels.values()
        for name, what in (
            (AOV_NAME, "material index"),
            (OBJECT_AOV, "object index"),
            (COVER_AOV, "cover"),
        ):
            if name not in read:
                raise OutputError(path, f"the engine wrote no '{name}' AOV for the {what}")
        material, objects = eevee_labels(read[AOV_NAME], read[OBJECT_AOV], *read[COVER_AOV])
        labels.update({AOV_NAME: material, OBJECT_AOV: objects})

    renamed = {f"{layer}.{AOV_NAME}": "Material Index", f"{layer}.{OBJECT_AOV}": "Object Index"}

    def edit(name: str, channels: dict) -> tuple[str, dict] | None:
        if name == f"{layer}.{COVER_AOV}":
            return None
        if name in renamed:
            values = labels[aovs[name]]
            name = f"{layer}.{renamed[name]}"
            channels = {f"{name}.X": values}
        elif name == f"{layer}.Depth":
            channels = {
                key: np.where(z >= clip_end * (1.0 - 1e-4), BACKGROUND_DEPTH_WRITTEN, z).astype(
                    np.float32
                )
                for key, z in channels.items()
            }
        return name, channels

    rewrite_exr(path, edit, prepare)


#: Share of a pixel's filter weight that must fall on participating materials for
#: EEVEE's pixel to be labelled with one (below it, the pixel is mostly other surfaces).
MIN_COVER = 0.5

#: How far a de-mixed label may be from a whole number and still be one surface's.
LABEL_TOLERANCE = 0.02


def eevee_labels(
    material: np.ndarray,
    objects: np.ndarray,
    cover: np.ndarray,
    material_sq: np.ndarray,
    objects_sq: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Material and Object Index from EEVEE's filtered AOVs, as Cycles would label them.

    EEVEE filters AOVs like colours: an edge pixel holds the filter-weighted mean of
    the slots (object numbers) of the surfaces it covers, with 0 for surfaces of
    other materials. Rounding that mean names a slot no surface in the pixel has
    (slot 3 at a third of the weight reads 1) and an object that is not there, so
    the post would scatter such a pixel with another material's profile, and the
    pixels around an edge would find an object touching them where there is none
    (unlit: ``SSSParams.contact``), darkening every silhouette. Divided by the
    cover (the weight on participating materials), a pixel of one participating
    surface reads whole numbers (:data:`LABEL_TOLERANCE`) whose squares are the
    means of the squared labels (a mix has a spread: two objects 1 and 3 of one
    material, half and half, read 2 but 5 for the square); one that mixes two
    participating surfaces is resolved by :func:`_unmix_pairs` into the one that
    holds most of its weight. A pixel is labelled only where that surface holds
    at least :data:`MIN_COVER` of its weight, as in Cycles, whose index passes
    come from one surface a pixel's samples hit. Any other covered pixel gets no
    slot (0: no subsurface there) and a labelled neighbour's object, so the post's
    samples that land on it see their own surface's edge.

    Parameters
    ----------
    material, objects : (H, W) float, the AOVs ``cvsss_material`` and ``cvsss_object``
    cover, material_sq, objects_sq : (H, W) float, the channels of ``cvsss_cover``:
        the weight on participating materials and the weighted sums of the squared
        slots and object numbers

    Returns
    -------
    material, objects : (H, W) float32 whole numbers
    """
    cover = np.asarray(cover, dtype=np.float64)
    covered = cover >= MIN_COVER
    safe = np.where(covered, cover, 1.0)
    unmixed = [np.asarray(v, dtype=np.float64) / safe for v in (material, objects)]
    squares = [np.asarray(v, dtype=np.float64) / safe for v in (material_sq, objects_sq)]
    wholes = [np.rint(v) for v in unmixed]
    one = covered.copy()
    for value, square, whole in zip(unmixed, squares, wholes):
        one &= np.abs(value - whole) <= LABEL_TOLERANCE
        # The spread of the labels (float32 sums: relative to the square's size).
        one &= np.abs(square - value * value) <= LABEL_TOLERANCE * np.maximum(1.0, whole)
    slots = np.where(one, wholes[0], 0.0)
    numbers = np.where(one, wholes[1], 0.0)
    _unmix_pairs(slots, numbers, one, covered & ~one, unmixed, wholes, cover)
    numbers = _spread(numbers, one, (cover > 0) & ~one, MIXED_REACH)
    return slots.astype(np.float32), numbers.astype(np.float32)


#: Half the side of the window searched for the surfaces a mixed pixel may hold.
PAIR_WINDOW = 3


def _unmix_pairs(slots, numbers, one, mixed, unmixed, rounded, cover) -> None:
    """Label in place each ``mixed`` pixel whose labels are two surfaces' mix.

    ``unmixed`` and ``rounded``: the labels over the cover, and those rounded. The
    candidates are the (slot, object) labels that some pixel of the frame
    holds whole and that a pixel within :data:`PAIR_WINDOW` rounds to (a thin
    object may have no whole pixel near its edge: every pixel of it mixes a
    little of what surrounds it). The mix weight ``w`` of each pair of candidates
    is fitted to both means at once (least squares); a pair that explains them
    within :data:`LABEL_TOLERANCE` gives the pixel its dominant surface's labels
    when that surface holds at least :data:`MIN_COVER` of the pixel's weight.
    A Python loop over the mixed pixels, about 20 µs each (a few thousand at 1080p).
    """
    m_bar, o_bar = unmixed
    known = set(zip(slots[one].tolist(), numbers[one].tolist()))
    for y, x in zip(*np.nonzero(mixed)):
        y0, y1 = max(y - PAIR_WINDOW, 0), y + PAIR_WINDOW + 1
        x0, x1 = max(x - PAIR_WINDOW, 0), x + PAIR_WINDOW + 1
        near = zip(
            rounded[0][y0:y1, x0:x1].ravel().tolist(), rounded[1][y0:y1, x0:x1].ravel().tolist()
        )
        labels = sorted(known.intersection(near))
        best = None
        for i, (j, a) in enumerate(labels):
            for k, b in labels[i + 1 :]:
                dm, do = m_bar[y, x] - k, o_bar[y, x] - b
                norm = (j - k) ** 2 + (a - b) ** 2
                w = min(max(((j - k) * dm + (a - b) * do) / norm, 0.0), 1.0)
                miss = max(abs(w * (j - k) - dm), abs(w * (a - b) - do))
                if miss <= LABEL_TOLERANCE and (best is None or miss < best[0]):
                    best = (miss, (j, a) if w >= 0.5 else (k, b), max(w, 1.0 - w))
        if best is not None and best[2] * cover[y, x] >= MIN_COVER:
            slots[y, x], numbers[y, x] = best[1]
            one[y, x] = True


#: Pixels a labelled object spreads into the mixed pixels next to it (EEVEE's
#: default 1.5-pixel filter mixes about that many).
MIXED_REACH = 3


def _spread(values: np.ndarray, known: np.ndarray, wanted: np.ndarray, steps: int) -> np.ndarray:
    """``values`` with each ``wanted`` pixel set from a ``known`` 8-neighbour (the
    largest value), repeated ``steps`` times so the known values reach that far."""
    values = values.copy()
    known = known.copy()
    height, width = values.shape
    for _ in range(steps):
        todo = wanted & ~known
        if not todo.any():
            break
        # The known values, -inf elsewhere and on a one-pixel border; each pixel's
        # best is the largest of its 8 neighbours' (shifted views of the padding).
        pad = np.pad(np.where(known, values, -np.inf), 1, constant_values=-np.inf)
        best = np.full(values.shape, -np.inf)
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                if dy == dx == 1:
                    continue
                np.maximum(best, pad[dy : dy + height, dx : dx + width], out=best)
        reached = todo & np.isfinite(best)
        values[reached] = best[reached]
        known |= reached
    return values
