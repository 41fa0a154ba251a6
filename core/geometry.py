"""The SSS pixels of a frame and what every estimator needs to know about them.

:func:`geometry_of` finds the pixels that scatter (a participating material and a
surface) and computes, once per frame, their pixel footprint, the direct
radius ``r0 = sqrt(w² + h²)/2`` (P Sec. 5), the distant energy ratio γ and the
sampling bounds of the profile. The Monte Carlo estimator (core.mc) and the
separable passes (core.separable) both work from this :class:`Geometry`.

Surface distances
-----------------
With ``SSSParams.distance = "surface"`` the Monte Carlo estimator weighs each
sample by the profile at the true distance between the two surface points,
reconstructed from the depth buffer and the camera, times the area Jacobian
of the screen → surface mapping (docs/explanation/design.md §5.5). :class:`Surface` holds what that
needs per frame: the camera's unit footprint and principal point, and the
surface area each pixel covers, from one-sided differences of the
reconstructed positions (central where both neighbours continue the surface,
else the side with the smaller depth step, so an occlusion edge does not
inflate it), capped at :data:`MAX_TILT` times the
fronto-parallel area (grazing angles).

Material slots
--------------
Profiles, kernels and the "same material" tests work on the frame's *compact*
slots (:func:`core.frame.compact_slots`): its subsurface materials numbered
1..K, 0 for everything else.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from .backends.twins import compiled_module, compiled_side, numpy_side
from .frame import Frame, compact_slots, slot_keys
from .profiles.base import Profile, Region

#: Largest surface area of a pixel, in units of its fronto-parallel footprint (~83° tilt).
MAX_TILT = 8.0


@dataclass
class Surface:
    """The depth-buffer surface of a frame (scene units).

    Attributes
    ----------
    ortho : bool, orthographic camera
    unit : (w, h), pixel footprint at unit depth (perspective) or always (ortho)
    centre : (cx, cy), principal point in pixel coordinates
    area : (H·W,) float32, surface area each pixel covers (scene units²; the
        fronto-parallel footprint where the surface is unknown)
    normal : (H·W, 3) float32, unit normal of that patch in camera space (x right,
        y down, z along the view axis), turned towards the camera; the view
        direction's opposite where the surface is unknown. The geometric normal
        of the depth buffer, as Cycles' disk sampling uses the geometric normal;
        with the Object Index pass, of the pixel's own object only (a step never
        goes to a neighbour of another object, so the top's row at a block's foot
        keeps the top's normal).
    """

    ortho: bool
    unit: tuple[float, float]
    centre: tuple[float, float]
    area: np.ndarray
    normal: np.ndarray | None = None


def positions(camera, depth: np.ndarray, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """(H, W, 3) float64 camera-space points of the depth buffer (x right, y down, z depth).

    Pixel centres sit at integer coordinates; background (inf depth) gives inf.
    ``origin`` (y, x) is the image position of ``depth[0, 0]`` (a crop).
    """
    h, w = depth.shape
    wu, hu = camera.unit_footprint()
    cx, cy = camera.principal_point
    z = np.asarray(depth, dtype=np.float64)
    oy, ox = origin
    yy, xx = np.mgrid[oy : oy + h, ox : ox + w].astype(np.float64)
    scale = np.ones_like(z) if camera.type == "ORTHO" else z
    with np.errstate(invalid="ignore"):
        return np.stack([(xx - cx) * wu * scale, (yy - cy) * hu * scale, z], axis=-1)


@numpy_side("surface")
def surface(frame: Frame, backend: str = "numpy") -> Surface:
    """The :class:`Surface` of ``frame`` (see the module doc).

    ``backend`` (one of core.params.BACKENDS): where it resolves to numba, one
    compiled pass computes the same arrays bit for bit (:func:`_surface_compiled`;
    this NumPy version makes ~40 passes over (H, W, 3) float64 arrays).
    """
    cam = frame.camera
    wu, hu = cam.unit_footprint()
    ortho = cam.type == "ORTHO"
    z = frame.depth.astype(np.float64)
    h, w = z.shape
    p = positions(cam, frame.depth, frame.origin)
    flat = (wu * hu) * (np.ones_like(z) if ortho else z * z)

    objects = frame.objects

    def tangent(axis: int) -> np.ndarray:
        """Per-pixel step along ``axis``: central where both neighbours continue the
        surface (depth steps within a factor 2), else the side with the smaller step;
        never towards a neighbour of another object (with the Object Index pass)."""
        fwd = np.full_like(p, np.nan)
        bwd = np.full_like(p, np.nan)
        if axis == 1:
            fwd[:, :-1] = p[:, 1:] - p[:, :-1]
            bwd[:, 1:] = p[:, 1:] - p[:, :-1]
            if objects is not None:
                apart = objects[:, 1:] != objects[:, :-1]
                fwd[:, :-1][apart] = np.nan
                bwd[:, 1:][apart] = np.nan
        else:
            fwd[:-1] = p[1:] - p[:-1]
            bwd[1:] = p[1:] - p[:-1]
            if objects is not None:
                apart = objects[1:] != objects[:-1]
                fwd[:-1][apart] = np.nan
                bwd[1:][apart] = np.nan
        with np.errstate(invalid="ignore"):
            fwd[~np.isfinite(fwd).all(axis=-1)] = np.nan
            bwd[~np.isfinite(bwd).all(axis=-1)] = np.nan
            af, ab = np.abs(fwd[..., 2]), np.abs(bwd[..., 2])
            use_bwd = np.isnan(af) | (ab < af)
            central = (np.maximum(af, ab) <= 2.0 * np.minimum(af, ab) + 1e-6 * z) & np.isfinite(
                af + ab
            )
        one = np.where(use_bwd[..., None], bwd, fwd)
        return np.where(central[..., None], 0.5 * (fwd + bwd), one)

    with np.errstate(invalid="ignore", over="ignore"):
        cross = np.cross(tangent(1), tangent(0))
        norm = np.linalg.norm(cross, axis=-1)
        known = np.isfinite(norm) & (norm > 0)
        area = np.where(known, np.minimum(norm, MAX_TILT * flat), flat)
        normal = cross / np.where(known, norm, 1.0)[..., None]
    area = np.where(np.isfinite(z), area, 0.0)
    # Towards the camera: against the view ray (perspective) or the view axis (ortho).
    view = np.zeros_like(p)
    view[..., 2] = 1.0
    if not ortho:
        view[..., 0] = (
            np.arange(w, dtype=np.float64) + frame.origin[1] - cam.principal_point[0]
        ) * wu
        view[..., 1] = (
            np.arange(h, dtype=np.float64)[:, None] + frame.origin[0] - cam.principal_point[1]
        ) * hu
    view /= np.linalg.norm(view, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore"):
        facing = np.sum(normal * view, axis=-1)
    normal = np.where((facing > 0)[..., None], -normal, normal)
    normal = np.where(known[..., None], normal, -view).reshape(-1, 3).astype(np.float32)
    # z from x and y in float32, as the compiled sampling pass rebuilds it from its texel (which
    # keeps x, y and z's sign), so both backends see the same normals.
    xy = normal[:, 0] * normal[:, 0] + normal[:, 1] * normal[:, 1]
    normal[:, 2] = np.copysign(
        np.sqrt(np.maximum(np.float32(1.0) - xy, np.float32(0.0))), normal[:, 2]
    )
    return Surface(
        ortho, (wu, hu), cam.principal_point, area.reshape(-1).astype(np.float32), normal
    )


@compiled_side("surface")
def _surface_compiled(frame: Frame, backend: str = "numpy") -> Surface:
    """:func:`surface` in one compiled pass over the pixels: the same arrays."""
    cam = frame.camera
    wu, hu = cam.unit_footprint()
    oy, ox = frame.origin
    objects = frame.objects
    area, normal = compiled_module("surface").surface_arrays(
        np.ascontiguousarray(frame.depth, dtype=np.float32),
        np.zeros((1, 1), np.int32) if objects is None else np.ascontiguousarray(objects),
        objects is not None,
        int(ox),
        int(oy),
        float(wu),
        float(hu),
        float(cam.principal_point[0]),
        float(cam.principal_point[1]),
        bool(cam.type == "ORTHO"),
        MAX_TILT,
    )
    return Surface(cam.type == "ORTHO", (wu, hu), cam.principal_point, area, normal)


@dataclass
class Geometry:
    """Per-frame quantities of the SSS pixels that do not depend on sampling.

    All per-pixel arrays have leading length P (number of SSS pixels), in
    row-major order of the image.

    For a cropped frame (:class:`core.frame.Crop`), ``shape`` and ``index``
    address the crop's arrays while ``x``, ``y`` are image coordinates (they
    seed the per-pixel streams and place samples, so a crop computes what
    the whole image computes).

    Attributes
    ----------
    shape : (H, W) of the frame's arrays
    index : (P,) int64, flat pixel index ``y·W + x`` into the frame's arrays
    x, y : (P,) int64, column and row in the image
    mat : (P,) int32, compact material slot
    slots : (H·W,) int32, compact slot of every pixel (0: no subsurface)
    depth : (P,) float64, scene units
    fw, fh : (P,) float64, pixel footprint, scene units per pixel
    r0 : (P,) float64, direct-scattering radius, scene units
    gamma : (P, 3) float64, distant energy ratio per channel
    weight_scale : (P, 3) float64, γ_c / (distant mass of channel c)
    lo, hi : (P, 3) float64, sampling bounds in the profile's u-space
    chromatic : (P,) bool, the slot's channels have different profiles
    weight : (P,) float64, Subsurface Weight w in [0, 1] (the material's, or the
        pixel's where the frame carries a per-pixel weight)
    direct : (P, 3) float32 or None, the direct part of B (lighting minus the
        frame's indirect pass, ≥ 0; all of B without one)
    surface : Surface or None, for surface-distance weights (None: planar radius)
    objects : (H·W,) int32 or None, the Object Index pass of every pixel (None: the
        frame has none; every pixel counts as one object)
    origin : (y, x), image coordinates of the frame's pixel (0, 0) (a crop's origin)
    image : (H, W) of the whole image, or None (the frame is the whole image)
    core : (P,) bool or None, the pixels inside a crop's core (None: all): the
        frame-level figures (samples, fall-backs) count these only
    """

    shape: tuple[int, int]
    index: np.ndarray
    x: np.ndarray
    y: np.ndarray
    mat: np.ndarray
    slots: np.ndarray
    depth: np.ndarray
    fw: np.ndarray
    fh: np.ndarray
    r0: np.ndarray
    gamma: np.ndarray
    weight_scale: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    chromatic: np.ndarray
    weight: np.ndarray | None = None
    direct: np.ndarray | None = None
    surface: Surface | None = None
    objects: np.ndarray | None = None
    origin: tuple[int, int] = (0, 0)
    image: tuple[int, int] | None = None
    core: np.ndarray | None = None

    @property
    def image_shape(self) -> tuple[int, int]:
        """(H, W) of the whole image (pixels outside it are off screen)."""
        return self.shape if self.image is None else self.image

    # Per-channel column operations: NumPy's reductions along a length-3 axis cost
    # 5-6x more (the same values: (γ_0 + γ_1) + γ_2 is the order sum() takes).
    @cached_property
    def gamma_sum(self) -> np.ndarray:
        """(P,) Σ_c γ_c."""
        g = self.gamma
        return g[:, 0] + g[:, 1] + g[:, 2]

    @property
    def size(self) -> int:
        return int(self.index.shape[0])

    @cached_property
    def gamma_max(self) -> np.ndarray:
        """(P,) largest γ over channels (the ε_u test of P Eq. 18)."""
        if not self.size:
            return np.zeros(0)
        g = self.gamma
        return np.maximum(np.maximum(g[:, 0], g[:, 1]), g[:, 2])

    def at(self, image: np.ndarray) -> np.ndarray:
        """(P, ...) values of an (H, W, ...) image at the SSS pixels (same dtype)."""
        return take_rows(image, self.index, self.shape)

    def mask(self) -> np.ndarray:
        """(H, W) bool mask of the SSS pixels."""
        m = np.zeros(self.shape[0] * self.shape[1], dtype=bool)
        m[self.index] = True
        return m.reshape(self.shape)

    # The images of the Geometry's own values, made once per Geometry and read-only:
    # GeometryCache hands them on to the frames that reuse it (the γ map is a fresh
    # 25 MB array per 1920×1080 frame otherwise; its first writes cost 4-44 ms).
    @cached_property
    def mask_image(self) -> np.ndarray:
        """(H, W) bool, read-only: :meth:`mask`."""
        return _read_only(self.mask())

    def gamma_image(self, backend: str = "numpy") -> np.ndarray:
        """(H, W, 3) float32, read-only: γ at the SSS pixels, 0 elsewhere (``to_image``;
        every backend gives the same image, made once)."""
        return self.memo(
            "gamma_image", lambda: _read_only(self.to_image(self.gamma, backend=backend))
        )

    @property
    def reused(self) -> bool:
        """This Geometry was handed on by a GeometryCache hit: a still scene's, reused at
        least once, and likely again. Work that depends on the lighting too, but whose
        buffers could serve the next frame, is kept in :attr:`memos` for such Geometries
        only: a moving scene's Geometry would hold it for nothing."""
        return self.__dict__.get("_reused", False)

    @property
    def memos(self) -> dict[str, Any]:
        """Values made once per Geometry from its own arrays (see :meth:`memo`), by name.

        One dict, shared by the Geometries a GeometryCache hands on for the frames
        that reuse this one: a consumer may take a value out while it writes into it
        (``memos.pop``) and put it back when done, so that no two calls share it.
        """
        return self.__dict__.setdefault("_memos", {})

    def memo(self, name: str, make: Callable[[], Any]) -> Any:
        """``make()``, made on first use and kept under ``name`` (:attr:`memos`).

        For values of the Geometry's own arrays (and of the passes it was prepared
        from: depth, material, objects, which a GeometryCache hit has bit for bit),
        never of the lighting. ``make`` must give the same value whenever called.
        """
        memos = self.memos
        value = memos.get(name)
        if value is None:
            value = memos[name] = make()
        return value

    def to_image(
        self, values: np.ndarray, fill: float = 0.0, dtype=np.float32, backend: str = "numpy"
    ) -> np.ndarray:
        """Scatter (P, ...) values into an (H, W, ...) image, ``fill`` elsewhere.

        Float values into a float32 image are clipped to ±float32 max (NaN kept);
        where ``backend`` resolves to numba that runs as one compiled pass (the
        ``float_image`` twin: the same values).
        """
        return _to_image(self.shape, self.index, values, fill, dtype, backend)


@numpy_side("float_image")
def _to_image(
    shape: tuple[int, int],
    index: np.ndarray,
    values: np.ndarray,
    fill: float = 0.0,
    dtype=np.float32,
    backend: str = "numpy",
) -> np.ndarray:
    """:meth:`Geometry.to_image` of a Geometry of image ``shape`` and pixels ``index``."""
    values = np.asarray(values)
    if np.dtype(dtype).kind == "f" and values.dtype.kind == "f":
        big = np.finfo(dtype).max
        values = np.clip(values, -big, big)
    out = np.full((shape[0] * shape[1], *values.shape[1:]), fill, dtype=dtype)
    out[index] = values
    return out.reshape(*shape, *values.shape[1:])


def _float_values(shape, index, values, fill=0.0, dtype=np.float32, backend="numpy") -> bool:
    """The compiled side of ``float_image`` takes (P,) or (P, C) floats into float32."""
    return (
        np.dtype(dtype) == np.float32
        and np.asarray(values).dtype.kind == "f"
        and np.ndim(values) in (1, 2)
    )


@compiled_side("float_image", supports=_float_values)
def _to_image_compiled(shape, index, values, fill=0.0, dtype=np.float32, backend="numpy"):
    """:func:`_to_image` of float values into float32 in one compiled pass."""
    values = np.asarray(values)
    out = compiled_module("image").float_image(values, index, shape[0] * shape[1], fill)
    return out.reshape(*shape, *values.shape[1:])


def take_rows(image: np.ndarray, index: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(P, ...) pixels ``index`` of an (H, W, ...) ``image`` (``shape`` = (H, W)).

    ``np.take`` along the pixel axis: the same values as ``image.reshape(H·W,
    ...)[index]``, 4-5x faster for multi-channel images (NumPy's fancy indexing
    of rows does not use the contiguous row copy ``take`` does).
    """
    flat = image.reshape(shape[0] * shape[1], *image.shape[2:])
    return np.take(flat, index, axis=0)


def light_scale(
    frame: Frame, profile: Profile, rows: np.ndarray | None = None, backend: str = "numpy"
) -> np.ndarray:
    """(3,) float64, linear: mean lighting pass over the scattering pixels of ``frame``.

    The frame-level yardstick of per-pixel rules (the temporal reuse's ε). A
    crop carries its whole image's value (:attr:`core.frame.Crop.light_scale`)
    so that tiles use the same one; a whole frame computes it here. Floored at
    1e-12 per channel (a black frame). ``rows``: (P, 3) float64, the lighting at
    the pixels of the whole frame's Geometry (``geom.at(frame.lighting)`` of
    :func:`geometry_of` of ``frame`` and ``profile``), which are those same pixels in
    the same order: used instead of finding them again (the same value). ``backend``:
    the mean's (the ``row_mean`` twin: the same value).
    """
    if frame.crop is not None and frame.crop.light_scale is not None:
        return np.asarray(frame.crop.light_scale, dtype=np.float64)
    if rows is None or frame.crop is not None:
        slots = compact_slots(frame.material.reshape(-1), slot_keys(frame.materials))
        scatters = np.zeros(max(profile.n_slots, 1), dtype=bool)
        scatters[: profile.n_slots] = profile.scatters()
        ok = (slots > 0) & (slots < profile.n_slots) & np.isfinite(frame.depth.reshape(-1))
        ok[ok] = scatters[slots[ok]]
        rows = frame.lighting.reshape(-1, 3)[ok].astype(np.float64)
    mean = row_mean(rows, backend) if rows.size else np.zeros(3)
    return np.maximum(mean, 1e-12)


@numpy_side("row_mean")
def row_mean(rows: np.ndarray, backend: str = "numpy") -> np.ndarray:
    """(3,) float64: the mean of (P, 3) float ``rows`` over the P rows, P > 0.

    NumPy sums a C-contiguous (P, 3) array's rows one after the other (the inner loop
    runs over the 3 channels); where ``backend`` resolves to numba so does one compiled
    pass over float64 rows, without NumPy's per-row loop overhead (the same value).
    """
    return rows.mean(axis=0)


def _float64_rows(rows: np.ndarray, backend: str = "numpy") -> bool:
    """The compiled mean takes C-contiguous (P, 3) float64 rows, P > 0 (NumPy's order
    of the sum is then row after row)."""
    return (
        rows.dtype == np.float64
        and rows.ndim == 2
        and rows.shape[1] == 3
        and rows.shape[0] > 0
        and rows.flags.c_contiguous
    )


@compiled_side("row_mean", supports=_float64_rows)
def _row_mean_compiled(rows: np.ndarray, backend: str = "numpy") -> np.ndarray:
    """:func:`row_mean` as one compiled pass: the sums row after row, then the division
    by P (NumPy's mean divides the sums by the count)."""
    return compiled_module("image").row_sums(rows) / rows.shape[0]


def distant_region(
    profile: Profile, r0: np.ndarray, mat: np.ndarray, backend: str = "numpy"
) -> Region:
    """``profile.region(r0, mat)``: γ, weight scale and sampling bounds of P pixels
    (compiled for the Burley profile where ``backend`` resolves to numba)."""
    return profile.region(r0, mat, backend=backend)


def geometry_of(
    frame: Frame,
    profile: Profile,
    surface_distance: bool = False,
    core_only: bool = False,
    margin: int = 0,
    backend: str = "numpy",
) -> Geometry:
    """Find the SSS pixels of ``frame`` and their footprint, r0, γ and sampling bounds.

    Parameters
    ----------
    frame : core.frame.Frame
        Uses its depth (planar, scene units, inf = background), Material Index
        pass, camera and material table.
    profile : core.profiles.Profile
        Built over the frame's compact slots (see module doc).
    surface_distance : bool
        Also compute the frame's :class:`Surface` (surface-distance weights).
    core_only : bool
        For a cropped frame, take the SSS pixels of its core only: the halo
        then serves as passes to sample (and history to reproject from),
        without being processed itself. A method whose pixels read other
        pixels' results (the separable passes) must not ask for it.
    margin : int
        With ``core_only``, also take the pixels up to ``margin`` beyond the core
        (clipped to the window): a method that reads its 3×3 neighbours' own
        estimates (temporal reuse) needs them computed as the whole image would.
    backend : str
        ``SSSParams.backend``: computes the :class:`Surface` and the Burley region
        compiled where it resolves to numba (the same arrays, see :func:`surface`
        and :func:`distant_region`).

    Returns
    -------
    Geometry
    """
    h, w = frame.shape
    slots = compact_slots(frame.material.reshape(-1), slot_keys(frame.materials))
    depth_flat = frame.depth.reshape(-1)
    scatters = np.zeros(max(profile.n_slots, 1), dtype=bool)
    scatters[: profile.n_slots] = profile.scatters()
    ok = (slots > 0) & (slots < profile.n_slots) & np.isfinite(depth_flat)
    if core_only and frame.crop is not None:
        (oy, ox), (y0, y1, x0, x1) = frame.crop.origin, frame.crop.core
        inside = np.zeros((h, w), dtype=bool)
        inside[
            max(y0 - oy - margin, 0) : y1 - oy + margin,
            max(x0 - ox - margin, 0) : x1 - ox + margin,
        ] = True
        ok &= inside.reshape(-1)
    ok[ok] = scatters[slots[ok]]
    index = np.flatnonzero(ok).astype(np.int64)
    mat = slots[index]
    z = depth_flat[index].astype(np.float64)
    fw, fh = frame.camera.footprint(z)
    r0 = 0.5 * np.sqrt(fw * fw + fh * fh)
    region = distant_region(profile, r0, mat, backend)
    y, x = np.divmod(index, w)
    core = None
    if frame.crop is not None:
        oy, ox = frame.crop.origin
        y += oy
        x += ox
        y0, y1, x0, x1 = frame.crop.core
        core = (y >= y0) & (y < y1) & (x >= x0) & (x < x1)
    return Geometry(
        shape=(h, w),
        index=index,
        x=x,
        y=y,
        mat=mat,
        slots=slots,
        depth=z,
        fw=fw,
        fh=fh,
        r0=r0,
        gamma=region.gamma,
        weight_scale=region.weight_scale,
        lo=region.lo,
        hi=region.hi,
        chromatic=profile.chromatic()[mat] if index.size else np.zeros(0, dtype=bool),
        weight=pixel_weights(frame, index, mat),
        direct=_direct(frame, index),
        surface=surface(frame, backend) if surface_distance and index.size else None,
        objects=None if frame.objects is None else frame.objects.reshape(-1),
        origin=frame.origin,
        image=None if frame.crop is None else frame.image_shape,
        core=core,
    )


def pixel_weights(frame: Frame, index: np.ndarray, mat: np.ndarray) -> np.ndarray:
    """(P,) float64 Subsurface Weight of the pixels ``index`` (slots ``mat``): the
    material's, or the frame's per-pixel weight where it has one (not NaN)."""
    keys = slot_keys(frame.materials)
    weights = np.array([1.0] + [frame.materials[int(k)].weight for k in keys])
    weight = weights[mat]
    if frame.sss_weight is not None:
        per_pixel = frame.sss_weight.reshape(-1)[index].astype(np.float64)
        weight = np.where(np.isnan(per_pixel), weight, per_pixel)
    return weight


def _direct(frame: Frame, index: np.ndarray) -> np.ndarray:
    """(P, 3) float32 direct part of the lighting pass at ``index`` (minus the
    frame's indirect pass, ≥ 0; all of it without one)."""
    direct = take_rows(frame.lighting, index, frame.shape)
    if frame.indirect is not None:
        indirect = take_rows(frame.indirect, index, frame.shape)
        direct = np.maximum(direct - indirect, np.float32(0.0))
    return direct.astype(np.float32, copy=False)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


#: Values a Geometry computes once from its own arrays (cached properties and
#: :attr:`Geometry.memos`), handed on by GeometryCache hits.
_CARRIED = ("gamma_sum", "gamma_max", "mask_image", "_memos")


def _snapshot(a: np.ndarray | None) -> np.ndarray | None:
    """A contiguous copy of ``a`` to compare later frames' passes with."""
    return None if a is None else np.array(a, order="C", copy=True)


def _same_bits(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """True when both are None or hold the same bits (NaN matches itself, −0 ≠ 0)."""
    if a is None or b is None:
        return a is b
    if a.dtype != b.dtype or a.shape != b.shape:
        return False
    return np.array_equal(np.ascontiguousarray(a).view(np.uint8), b.view(np.uint8))


class GeometryCache:
    """:func:`geometry_of` that reuses the last frame's Geometry while its passes are unchanged.

    A lighting animation over a still scene (flashing lights, flickering
    candles, a still camera) renders the same Depth, Material Index and Object
    Index passes every frame: the SSS pixels, their footprints, γ, sampling
    bounds and depth-buffer surface are then the same, and only what depends on
    the lighting (the direct part, :attr:`Geometry.direct`) and the Subsurface
    Weight are taken from the new frame. Bit for bit what :func:`geometry_of`
    returns (tests/core/test_geometry.py). A reused 1920×1080 frame took 8–10
    ms (the comparison, the direct light and the weight) against 90–110 ms for
    :func:`geometry_of` with the compiled backend (docs/checks/geometry_reuse.py).

    Reuse needs the same pass bits, camera, crop, material table and profile
    object (core.profiles.factory.ProfileCache returns the same object while the
    materials are unchanged) and the same options; anything else prepares anew.
    One entry is kept per crop (the whole frame is one; a pooled tile processor
    of core.tiling serves many crops), at most :attr:`MAX_ENTRIES` and
    :attr:`MAX_BYTES`, the oldest dropped first; the newest is always kept. A
    stale entry is dropped before its crop is prepared anew, so a moving scene
    never holds two Geometries of one crop. Returned Geometries share their
    arrays with the cached one: callers must not write into them (none does).
    """

    #: Crops remembered (a 3840×2160 image in 256-pixel tiles has 135).
    MAX_ENTRIES = 256
    #: Bytes the entries may hold together (about one 3840×2160 frame's Geometry at
    #: 40 % SSS pixels; the newest entry is kept even when it alone holds more): a
    #: tile processor serving every crop of a large image keeps some of them, not all.
    MAX_BYTES = 1 << 30

    def __init__(self) -> None:
        # crop -> (key, profile, copies of the passes, Geometry)
        self._entries: dict[tuple | None, tuple] = {}
        #: Frames served from the cache (for tests and reports).
        self.hits = 0

    def get(self, frame: Frame, profile: Profile, **options) -> Geometry:
        """:func:`geometry_of` (same keyword options), reusing the last result where valid."""
        # What geometry_of() reads of the crop (its light_scale changes with the lighting).
        crop = frame.crop and (frame.crop.image, frame.crop.origin, frame.crop.core)
        key = (
            frame.shape,
            frame.camera,
            tuple(slot_keys(frame.materials).tolist()),
            tuple(sorted(options.items())),
        )
        passes = (frame.depth, frame.material, frame.objects)
        entry = self._entries.get(crop)
        if (
            entry is not None
            and key == entry[0]
            and profile is entry[1]
            and all(_same_bits(a, b) for a, b in zip(entry[2], passes))
        ):
            self.hits += 1
            geom = entry[3]
            fresh = dataclasses.replace(
                geom,
                weight=pixel_weights(frame, geom.index, geom.mat),
                direct=_direct(frame, geom.index),
                # The same values; a view of this frame's pass, as geometry_of() gives.
                objects=None if frame.objects is None else frame.objects.reshape(-1),
            )
            # What is made once per Geometry from its own arrays carries over (the
            # same arrays).
            for name in _CARRIED:
                if name in geom.__dict__:
                    fresh.__dict__[name] = geom.__dict__[name]
            fresh.__dict__["_reused"] = True
            return fresh
        self._entries.pop(crop, None)  # stale: free it before preparing anew
        geom = geometry_of(frame, profile, **options)
        entries = self._entries
        entries[crop] = (key, profile, tuple(_snapshot(a) for a in passes), geom)
        while len(entries) > 1 and (
            len(entries) > self.MAX_ENTRIES
            or sum(_entry_bytes(e) for e in entries.values()) > self.MAX_BYTES
        ):
            del entries[next(iter(entries))]
        return geom


def _entry_bytes(entry: tuple) -> int:
    """Bytes of the arrays a GeometryCache entry holds (its copies of the passes and
    its Geometry's arrays, surface, images and memos)."""
    geom = entry[3]
    arrays = [*entry[2], *vars(geom).values()]
    if geom.surface is not None:
        arrays += [geom.surface.area, geom.surface.normal]
    for value in geom.memos.values():
        arrays += value if isinstance(value, tuple) else [value]
    return sum(a.nbytes for a in arrays if isinstance(a, np.ndarray))
