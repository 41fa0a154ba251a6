"""The per-frame input of the core: Blender passes plus camera and materials.

Image arrays follow the EXR convention: row 0 is the *top* of the image,
column 0 the left. (Blender's ``Image.pixels`` start at the bottom row; the
add-on flips when it creates image datablocks.) Colours are linear,
scene-referred Rec. 709; depth is planar, in scene units.

Material slots
--------------
The Material Index pass may hold any value up to 2³¹−1. Profiles, kernels
and the "same material" tests work on *compact* slots: the sorted subsurface
materials of the frame numbered 1..K, 0 for everything else
(:func:`compact_slots`), so memory grows with the number of distinct
materials, not with the largest index.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .camera import Camera

#: Depths at or beyond this (Blender writes 1e10 for the background) are "no surface".
BACKGROUND_DEPTH = 1e9

#: Motion vectors are clipped to ±this many pixels (far beyond any image).
MAX_MOTION = 1e7

#: Blender's Pass Index is a short: the largest material slot (the Material Index
#: pass) and object index it stores.
MAX_PASS_INDEX = 2**15 - 1

#: The Principled BSDF's subsurface methods (Blender identifiers). A material of the
#: passes scatters with one of them in Cycles; the post models each
#: (core.profiles.random_walk).
SUBSURFACE_METHODS = ("BURLEY", "RANDOM_WALK", "RANDOM_WALK_SKIN")

#: A linked (textured) Base Color is resolved to the mean of the Diffuse Color pass over
#: the material's pixels, rounded to this many decimals (linear): a still scene keeps one
#: value, and so one profile, while the pass's noise moves the mean in its last digits.
BASE_COLOR_DIGITS = 3

#: Object indices are clipped to [0, this] (the compiled sampling pass keeps slot and object
#: in one float32, exact below 2**24).
MAX_OBJECTS = 2**15


# -- material slots ----------------------------------------------------------------
def slot_keys(materials) -> np.ndarray:
    """(K,) int64 Material Index values of the subsurface materials, sorted."""
    return np.array(sorted(int(s) for s in materials), dtype=np.int64)


#: compact_slots looks keys below this up in a table (else a binary search).
_TABLE_KEYS = 1 << 16


def compact_slots(material: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Material Index values → compact slots: ``keys[i]`` → i + 1, anything else → 0.

    Parameters
    ----------
    material : (...) int array, Material Index pass values
    keys : (K,) int64, sorted Material Index values of the subsurface materials

    Returns
    -------
    (...) int32 compact slots in [0, K].

    >>> compact_slots(np.array([0, 7, 2**31 - 1, 5]), np.array([7, 2**31 - 1])).tolist()
    [0, 1, 2, 0]
    """
    material = np.asarray(material)
    if keys.size == 0:
        return np.zeros(material.shape, np.int32)
    integer = material.dtype.kind in "iu" and np.can_cast(material.dtype, np.intp)
    if integer and keys[0] >= 1 and keys[-1] < _TABLE_KEYS:
        # A lookup table over 0…max key (0 elsewhere); values outside it clip to an
        # end that reads 0 (keys start at 1). One pass: 0.8 ms against 20 ms for the
        # binary search on 921 600 values (one-off timeit).
        table = np.zeros(int(keys[-1]) + 2, np.int32)
        table[keys] = np.arange(1, keys.size + 1, dtype=np.int32)
        return np.take(table, material, mode="clip")
    pos = np.searchsorted(keys, material)
    hit = keys[np.minimum(pos, keys.size - 1)] == material
    return np.where(hit, pos + 1, 0).astype(np.int32)


def resolve_base_colors(
    materials: dict, material: np.ndarray, albedo: np.ndarray, depth: np.ndarray
) -> dict:
    """``materials`` with each linked Base Color taken from the Diffuse Color pass.

    The random-walk model (core.profiles.random_walk) needs one albedo per
    material. Where the Base Color is textured (option ``base_color_linked``)
    the pass render cannot know it before the frame is rendered, so the mean of
    the Diffuse Color pass over the material's pixels with a surface stands in,
    rounded to :data:`BASE_COLOR_DIGITS` decimals. A material without pixels in
    the frame keeps its ``base_color`` (the socket's value). Burley materials
    and unlinked Base Colors are returned as they are.

    Parameters
    ----------
    materials : dict slot -> MaterialSpec
    material : (H, W) int, Material Index pass
    albedo : (H, W, 3) float, Diffuse Color pass, linear
    depth : (H, W) float, planar depth (inf: background)

    Returns
    -------
    dict slot -> MaterialSpec (``materials`` itself when nothing is linked)
    """
    linked = [
        s
        for s, spec in materials.items()
        if spec.method != "BURLEY" and spec.options.get("base_color_linked")
    ]
    if not linked:
        return materials
    out = dict(materials)
    surface = np.isfinite(depth)
    for slot in linked:
        pixels = surface & (material == slot)
        if not pixels.any():
            continue
        mean = albedo[pixels].astype(np.float64).mean(axis=0)
        color = [round(min(max(float(v), 0.0), 1.0), BASE_COLOR_DIGITS) for v in mean]
        spec = out[slot]
        out[slot] = dataclasses.replace(spec, options={**spec.options, "base_color": color})
    return out


def compact_materials(materials) -> dict:
    """The frame's MaterialSpecs keyed by compact slot 1..K (their own ``slot`` unchanged)."""
    return {i: materials[int(k)] for i, k in enumerate(slot_keys(materials), 1)}


@dataclass(frozen=True)
class MaterialSpec:
    """Subsurface parameters of one material slot (Material Index pass value).

    Attributes
    ----------
    slot : int
        Material pass index, >= 1.
    name : str
        Blender material name.
    d : tuple of 3 floats
        Burley shape per channel, scene units (``radius·scale·0.25/π``).
    profile : str
        Profile name (``"burley"``; other profiles join via core.profiles).
    options : dict
        Profile-specific options (e.g. a measured preset), JSON-serialisable.
    weight : float
        Subsurface Weight w in [0, 1] of the Principled BSDF: Cycles mixes
        ``(1 − w)·diffuse + w·subsurface``, and so does the composite
        (docs/explanation/design.md §2.3). A linked (textured) weight travels per pixel instead
        (:attr:`Frame.sss_weight`).
    method : str
        The Principled BSDF's subsurface method, one of :data:`SUBSURFACE_METHODS`.
        For RANDOM_WALK and RANDOM_WALK_SKIN ``d`` stays Blender's mapping of the
        radius (the walk's mean free path, for RANDOM_WALK) and the profile takes
        the fitted model's shape and energy from ``options``
        (core.profiles.random_walk, core.profiles.energy): ``base_color`` (3
        floats, linear), ``subsurface_radius`` (3 floats), ``subsurface_scale``,
        ``subsurface_ior``, ``subsurface_anisotropy`` and ``base_color_linked``
        (true: the Base Color is textured; :class:`Frame` replaces ``base_color``
        by the mean of the Diffuse Color pass over the material's pixels). A
        sidecar without ``method`` (older ones) means BURLEY.
    """

    slot: int
    name: str
    d: tuple[float, float, float]
    profile: str = "burley"
    options: dict = field(default_factory=dict, compare=False)
    weight: float = 1.0
    method: str = "BURLEY"

    def __post_init__(self) -> None:
        slot = self.slot
        if isinstance(slot, bool) or not isinstance(slot, int) or not 1 <= slot <= MAX_PASS_INDEX:
            raise ValueError(
                f"material slot must be an integer in [1, {MAX_PASS_INDEX}], got {slot!r}"
            )
        d = tuple(float(v) for v in self.d)
        if len(d) != 3 or not all(np.isfinite(d)) or min(d) < 0:
            raise ValueError(
                f"material {self.name!r}: d must be 3 finite values >= 0, got {self.d!r}"
            )
        object.__setattr__(self, "d", d)
        weight = self.weight
        if isinstance(weight, bool) or not isinstance(weight, int | float) or not 0 <= weight <= 1:
            raise ValueError(
                f"material {self.name!r}: subsurface weight must be in [0, 1], got {weight!r}"
            )
        object.__setattr__(self, "weight", float(weight))
        if self.method not in SUBSURFACE_METHODS:
            raise ValueError(
                f"material {self.name!r}: subsurface method must be one of "
                f"{', '.join(SUBSURFACE_METHODS)}, got {self.method!r}"
            )

    def to_dict(self) -> dict:
        """JSON-ready form (the sidecar's entry); ``method`` is left out for BURLEY, as
        sidecars written before it was recorded leave it out."""
        out = {
            "slot": self.slot,
            "name": self.name,
            "d": list(self.d),
            "profile": self.profile,
            "options": dict(self.options),
            "weight": self.weight,
        }
        if self.method != "BURLEY":
            out["method"] = self.method
        return out

    @classmethod
    def from_dict(cls, data: dict) -> MaterialSpec:
        slot = data["slot"]
        if isinstance(slot, float) and slot.is_integer():  # 3.0 as written by some tools
            slot = int(slot)
        return cls(
            slot=slot,
            name=str(data.get("name", f"slot{data['slot']}")),
            d=tuple(data["d"]),
            profile=str(data.get("profile", "burley")),
            options=dict(data.get("options", {})),
            weight=float(data.get("weight", 1.0)),
            method=str(data.get("method", "BURLEY")),
        )


@dataclass(frozen=True)
class Crop:
    """Where the passes of a cropped frame (an image tile with its halo) sit in the image.

    A cropped frame keeps the whole image's camera (principal point, footprint)
    and its pixels keep their image coordinates, which seed the per-pixel
    random streams: processing a crop gives, on the pixels far enough from its
    edges, the values the whole image gives (core.tiling).

    Attributes
    ----------
    image : (H, W), pixels of the whole image (the camera's resolution)
    origin : (y, x), image coordinates of the crop's top-left pixel
    core : (y0, y1, x0, x1), image coordinates, end exclusive: the pixels this
        crop answers for (its tile); the frame-level figures of a result
        (samples, fall-backs, SSS pixel counts) count these pixels only
    light_scale : (3,) float or None, linear: the per-channel mean of the
        lighting pass over the whole image's scattering pixels. A per-pixel rule
        that needs a frame-level yardstick (the temporal reuse's ε) takes it
        from here, so a tile uses the whole image's value (None: the crop's own).
    """

    image: tuple[int, int]
    origin: tuple[int, int]
    core: tuple[int, int, int, int]
    light_scale: tuple[float, float, float] | None = None


def _finite_or_zero(a: np.ndarray) -> tuple[int, np.ndarray]:
    """(count of non-finite values, ``a`` with them set to 0): a new array when
    there are any, ``a`` itself otherwise (never changed in place)."""
    finite = np.isfinite(a)
    n_bad = a.size - int(np.count_nonzero(finite))
    return n_bad, (np.where(finite, a, 0.0) if n_bad else a)


def _clipped_index(a: np.ndarray, top: int) -> np.ndarray:
    """Finite float64 ``a`` rounded to the nearest integer in [0, top], as int32."""
    r = np.rint(a)
    # np.clip's bits: at 1280x720 this took 1.2 ms, with np.clip 4.6 ms (one-off timeit).
    np.maximum(r, 0.0, out=r)
    np.minimum(r, float(top), out=r)
    return r.astype(np.int32)


def _clean(name: str, array: np.ndarray, shape: tuple, channels: int | None) -> np.ndarray:
    a = np.asarray(array)
    want = shape if channels is None else (*shape, channels)
    if a.shape != want:
        raise ValueError(f"pass {name!r} has shape {a.shape}, expected {want}")
    return a


#: The Frame fields that hold one value per pixel (cropped, shifted, tiled alike).
PIXEL_PASSES = (
    "lighting",
    "albedo",
    "combined",
    "depth",
    "material",
    "motion",
    "sss_weight",
    "indirect",
    "objects",
)


@dataclass
class Frame:
    """Passes of one rendered frame.

    Attributes
    ----------
    number : int
        Frame number in the sequence.
    lighting : (H, W, 3) float32
        B, pre-integrated lighting without albedo: Diffuse Direct + Diffuse
        Indirect rendered with subsurface disabled; linear. Non-finite and
        negative values are replaced by 0 (counted in ``repaired``).
    albedo : (H, W, 3) float32
        Diffuse Color pass, linear.
    combined : (H, W, 3) float32
        Combined (beauty) pass without alpha, linear.
    depth : (H, W) float32
        Planar depth, scene units; >= 1e9 or non-finite is background.
    material : (H, W) int32
        Material Index pass, 0 = no subsurface.
    camera : Camera
    materials : dict[int, MaterialSpec]
        Subsurface materials by slot; a whole frame resolves their linked Base
        Colors from its Diffuse Color pass (:func:`resolve_base_colors`).
    motion : (H, W, 2) float32 or None
        Offset (dx, dy) in pixels from a pixel to where its surface was in the
        previous frame, x right and y down (EXR rows). None = static.
    source : str or None
        File the frame was read from (for messages).
    repaired : int
        Input values replaced because unusable: non-finite or negative
        lighting, albedo and combined values (-> 0), NaN depths
        (-> background), non-finite material and object indices (-> 0; no SSS) and
        motion vectors (-> off screen: the pixel's history is dropped).
    lighting_passes : tuple of str
        Passes summed into B (e.g. Diffuse Direct, Diffuse Indirect).
    sss_weight : (H, W) float32 or None
        Subsurface Weight per pixel in [0, 1] where a material's weight is
        linked (textured), written by the pass render through an AOV; NaN
        where the material's constant :attr:`MaterialSpec.weight` applies.
        None: every material's constant weight.
    crop : Crop or None
        The passes are a crop of the image (a tile with its halo; see
        core.tiling); None: the whole image, matching the camera.
    indirect : (H, W, 3) float32 or None
        The Diffuse Indirect part of ``lighting`` (linear; non-finite and
        negative values -> 0). The rest is direct light, which the hidden-light
        prior scales (SSSParams.hidden_light). None: all of B is direct.
    objects : (H, W) int32 or None
        Object Index pass: which object each pixel sees (0: the background or an
        object the pass render did not number). Cycles never scatters light from
        one object into another, so neither do the samples (SSSParams.contact).
        None: unknown (a pixel's object is taken to be its material's).
    """

    number: int
    lighting: np.ndarray
    albedo: np.ndarray
    combined: np.ndarray
    depth: np.ndarray
    material: np.ndarray
    camera: Camera
    materials: dict[int, MaterialSpec] = field(default_factory=dict)
    motion: np.ndarray | None = None
    source: str | None = None
    repaired: int = 0
    lighting_passes: tuple[str, ...] = ()
    sss_weight: np.ndarray | None = None
    crop: Crop | None = None
    indirect: np.ndarray | None = None
    objects: np.ndarray | None = None

    def map_pixels(self, fn, **changes) -> Frame:
        """A copy with ``fn`` applied to every per-pixel pass (:data:`PIXEL_PASSES`).

        ``fn`` maps an (H, W, …) array to an (H', W', …) array (a crop, a
        shift); passes that are None stay None; ``changes`` replace fields
        after that, as :func:`dataclasses.replace` does.
        """
        mapped = {name: getattr(self, name) for name in PIXEL_PASSES}
        mapped = {k: None if a is None else fn(a) for k, a in mapped.items()}
        return dataclasses.replace(self, **{**mapped, **changes})

    def __post_init__(self) -> None:
        depth = np.asarray(self.depth)
        if depth.ndim != 2 or depth.shape[0] < 1 or depth.shape[1] < 1:
            raise ValueError(f"pass 'depth' must be a 2D image, got shape {depth.shape}")
        shape = depth.shape
        if self.crop is not None:
            self._check_crop(shape)
        elif (self.camera.height, self.camera.width) != shape:
            raise ValueError(
                f"camera resolution {self.camera.width}x{self.camera.height} does not match "
                f"the passes ({shape[1]}x{shape[0]})"
            )
        repaired = 0
        # The colour passes (the Diffuse Indirect part only when the frame has one):
        # non-finite and negative values become 0 and count as repaired.
        optional = ("indirect",) if self.indirect is not None else ()
        for name in ("lighting", "albedo", "combined", *optional):
            with np.errstate(over="ignore", invalid="ignore"):  # > float32 max: inf, repaired
                a = _clean(name, getattr(self, name), shape, 3).astype(np.float32, copy=True)
            # NaN fails both comparisons, +inf the second, -inf and negatives the first.
            good = a >= 0
            good &= a < np.inf
            n_bad = a.size - int(np.count_nonzero(good))
            if n_bad:
                a[~good] = 0.0
                repaired += n_bad
            setattr(self, name, a)
        # +inf depth is how half-float files store the background; NaN is not
        # a depth at all, so it counts as repaired (and becomes background).
        repaired += int(np.count_nonzero(np.isnan(depth)))
        with np.errstate(over="ignore", invalid="ignore"):
            d = depth.astype(np.float32, copy=True)
        d[~np.isfinite(d) | (d <= 0) | (d >= BACKGROUND_DEPTH)] = np.inf
        self.depth = d
        m = np.asarray(_clean("material", self.material, shape, None), dtype=np.float64)
        n_bad, m = _finite_or_zero(m)
        repaired += n_bad
        self.material = _clipped_index(m, 2**31 - 1)
        if self.motion is not None:
            mv = np.asarray(_clean("motion", self.motion, shape, 2), dtype=np.float64)
            bad = ~np.isfinite(mv)
            repaired += int(np.count_nonzero(bad))
            # A pixel whose motion is unknown did not come from anywhere we know:
            # point it off screen, which drops its history (a disocclusion), as
            # does motion beyond any image size.
            mv[np.any(bad, axis=-1)] = MAX_MOTION
            mv = np.clip(mv, -MAX_MOTION, MAX_MOTION)
            self.motion = mv.astype(np.float32)
        if self.objects is not None:
            ob = np.asarray(_clean("objects", self.objects, shape, None), dtype=np.float64)
            n_bad, ob = _finite_or_zero(ob)
            repaired += n_bad
            self.objects = _clipped_index(ob, MAX_OBJECTS)
        if self.sss_weight is not None:
            sw = np.asarray(_clean("sss_weight", self.sss_weight, shape, None), dtype=np.float32)
            # Out-of-range weights are clipped (a texture may overshoot); NaN means
            # "the material's constant" and stays.
            self.sss_weight = np.clip(sw, 0.0, 1.0)
        for slot, spec in self.materials.items():
            if slot != spec.slot:
                raise ValueError(f"material table key {slot} does not match slot {spec.slot}")
        if self.crop is None:
            # A crop (core.tiling) carries the whole image's values: its tiles then
            # build the whole image's profile.
            self.materials = resolve_base_colors(
                self.materials, self.material, self.albedo, self.depth
            )
        self.repaired = repaired

    def _check_crop(self, shape: tuple[int, int]) -> None:
        crop = self.crop
        image = (self.camera.height, self.camera.width)
        (oy, ox), (y0, y1, x0, x1) = crop.origin, crop.core
        if tuple(crop.image) != image:
            raise ValueError(
                f"crop of a {crop.image[1]}x{crop.image[0]} image but the camera renders "
                f"{image[1]}x{image[0]}"
            )
        if not (0 <= oy and 0 <= ox and oy + shape[0] <= image[0] and ox + shape[1] <= image[1]):
            raise ValueError(
                f"crop {shape[1]}x{shape[0]} at (x {ox}, y {oy}) does not fit the "
                f"{image[1]}x{image[0]} image"
            )
        if not (oy <= y0 < y1 <= oy + shape[0] and ox <= x0 < x1 <= ox + shape[1]):
            raise ValueError(f"crop core {crop.core} is not a non-empty part of the crop")

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) in pixels (of the crop, for a cropped frame)."""
        return self.depth.shape

    @property
    def origin(self) -> tuple[int, int]:
        """(y, x) image coordinates of pixel (0, 0) of the passes."""
        return (0, 0) if self.crop is None else tuple(self.crop.origin)

    @property
    def image_shape(self) -> tuple[int, int]:
        """(H, W) of the whole image (the camera's resolution)."""
        return (self.camera.height, self.camera.width)

    @property
    def surface(self) -> np.ndarray:
        """(H, W) bool: pixels that see a surface (finite depth)."""
        return np.isfinite(self.depth)

    def d_table(self) -> np.ndarray:
        """(K + 1, 3) Burley ``d`` per compact slot (scene units; row 0: no subsurface).

        Rows follow :func:`compact_slots`: the K subsurface
        materials sorted by Material Index, so the table's size does not
        depend on the index values.
        """
        table = np.zeros((len(self.materials) + 1, 3))
        for slot, spec in compact_materials(self.materials).items():
            table[slot] = spec.d
        return table
