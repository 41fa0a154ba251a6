"""The separable passes: each SSS pixel reads its kernel's taps along x, then along y.

Runtime, per SSS pixel: each tap's scene-unit offset becomes pixels with the
pixel's footprint (:meth:`cvsss.core.camera.Camera.footprint` at its depth),
the source is read at the nearest pixel (``filter="nearest"``, default: like
the Monte Carlo estimator, B is constant per pixel, so sub-pixel taps read
the centre) or between the two nearest pixels (``"linear"``, what GPU bilinear
fetches do; it also spreads the sub-pixel part of the kernel over the
neighbours), and each read follows the surface: a pixel of another material or off screen
contributes the centre value, and so does a same-material pixel across a depth
discontinuity. ``follow="slope"`` (default) uses the Monte Carlo estimator's
bilateral rule, a read at screen distance r (scene units) falls back when
``|Δz| > depth_slope·r`` (SSSParams.depth_slope), so that separable and Monte
Carlo results differ only by their kernels; ``follow="exponential"`` is the
supplementary's depth correction (S.E), blending the read towards the centre
by ``1 − exp(−Δz²/(2τ))`` with τ the largest channel variance of the slot's
projected 1D kernel, which also shrinks the kernel on steep surfaces. With ``jitter``
the taps within ``jitter_threshold`` (33 %, as in the supplementary's Figure
S.7; Blender EEVEE's Jitter Threshold likewise randomises the samples below a
share of the radius, default 0.3) of the kernel range — the heavy inner
taps whose discrete steps show as bands — are moved per pixel, pass and frame
to a uniformly random position inside their own cell (pcg3d hash; fixed seed
⇒ identical reruns): the staircase a step edge produces becomes, on average,
the cell-filtered kernel, and the bands turn into unstructured noise. The
sparse outer taps stay put (coherent reads, low weights). Results are
clamped to >= 0 (SVD terms of rank ≥ 2 have negative lobes).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..backends.twins import compiled_module, compiled_side, numpy_side
from ..geometry import Geometry, geometry_of
from ..params import SeparableParams
from ..profiles.base import Profile
from ..sampling.qmc import pcg3d
from .kernels import SlotKernel, build_kernels

_INV_2_32 = 1.0 / 2**32


@dataclass
class _Tables:
    """Per-slot kernel tables (K = n_slots, n taps, J terms)."""

    offsets: np.ndarray  # (K, n) scene units
    width: np.ndarray  # (K, n) cell widths where jittered, else 0
    h: np.ndarray  # (K, n, 3J) float32, index term·3 + channel
    v: np.ndarray  # (K, n, 3J) float32
    inv2tau: np.ndarray  # (K,) 1/(2τ)


def _stack(kernels: dict[int, SlotKernel], n_slots: int, params: SeparableParams) -> _Tables:
    n, j = params.taps, params.terms
    off = np.zeros((n_slots, n))
    width = np.zeros((n_slots, n))
    h = np.zeros((n_slots, n, 3 * j), np.float32)
    v = np.zeros((n_slots, n, 3 * j), np.float32)
    inv2tau = np.zeros(n_slots)
    for s, k in kernels.items():
        off[s] = k.offsets
        if params.jitter:
            near = np.abs(k.offsets) <= params.jitter_threshold * k.range * (1.0 + 1e-12)
            near[n // 2] = False
            width[s] = np.where(near, k.cells[:, 1] - k.cells[:, 0], 0.0)
        h[s] = k.h.transpose(1, 0, 2).reshape(n, 3 * j)
        v[s] = k.v.transpose(1, 0, 2).reshape(n, 3 * j)
        inv2tau[s] = 0.5 / k.tau
    return _Tables(off, width, h, v, inv2tau)


@dataclass
class _Pixels:
    """SSS pixels sorted by slot, so per-slot constants apply to contiguous runs."""

    order: np.ndarray  # (P,) position in the Geometry of each sorted pixel
    runs: list  # [(slot, start, stop)]
    lengths: np.ndarray  # (R,) run lengths
    slots: np.ndarray  # (R,) run slots
    index: np.ndarray  # (P,) flat pixel index into the frame's arrays
    x: np.ndarray  # (P,) image coordinates (a crop's pixels keep theirs)
    y: np.ndarray
    mat: np.ndarray  # (P,) int32
    z: np.ndarray  # (P,) float32 depth
    inv_fw: np.ndarray  # (P,) float32 pixels per scene unit
    inv_fh: np.ndarray
    origin: tuple[int, int]  # (y, x) image coordinates of the frame's pixel (0, 0)
    image: tuple[int, int]  # (H, W) of the whole image
    core: np.ndarray | None  # (P,) bool, pixels whose reads are counted (None: all)
    #: The compiled vertical pass's layout (:func:`_columns`), made on its first use.
    columns: _Columns | None = None


@dataclass
class _Columns:
    """The compiled vertical pass's layout: the image arrays transposed (column-major)
    and the SSS pixels sorted by slot, then column, then row, so that a block of pixels
    and its reads run down contiguous memory, as the horizontal pass's run along rows."""

    px: _Pixels  # the pixels in that order; index: flat into the transposed arrays
    index: np.ndarray  # (P,) int64, flat index into the transposed arrays, row order
    depth: np.ndarray  # (W·H,) float32, the depth transposed
    slots: np.ndarray  # (W·H,) int32, the slots transposed


def _columns(px: _Pixels, shape: tuple[int, int], depth_flat, slots) -> _Columns:
    """:class:`_Columns` of the row-order pixels ``px`` of a frame of ``shape`` (H, W),
    with its (H·W,) depth and slots."""
    h, w = shape
    oy, ox = px.origin
    index = (px.x - ox) * h + (px.y - oy)
    perm = np.lexsort((px.y, px.x, px.mat))  # stable: the slots' runs stay in place
    cols = _Pixels(
        px.order[perm],
        px.runs,
        px.lengths,
        px.slots,
        index[perm],
        px.x[perm],
        px.y[perm],
        px.mat[perm],
        px.z[perm],
        px.inv_fw[perm],
        px.inv_fh[perm],
        px.origin,
        px.image,
        None if px.core is None else px.core[perm],
    )

    def transposed(a, dtype):
        return np.ascontiguousarray(np.asarray(a, dtype).reshape(h, w).T).reshape(-1)

    return _Columns(cols, index, transposed(depth_flat, np.float32), transposed(slots, np.int32))


def _pixels(geom: Geometry) -> _Pixels:
    order = np.argsort(geom.mat, kind="stable")
    mat = geom.mat[order]
    slots, starts, lengths = np.unique(mat, return_index=True, return_counts=True)
    runs = [(int(s), int(a), int(a + n)) for s, a, n in zip(slots, starts, lengths)]
    # A footprint below float32's range (a depth of 1e-40) gives an infinite 1/footprint:
    # its taps land off the image and read the centre, as any tap that leaves it.
    with np.errstate(over="ignore"):
        inv_fw = (1.0 / geom.fw[order]).astype(np.float32)
        inv_fh = (1.0 / geom.fh[order]).astype(np.float32)
    return _Pixels(
        order,
        runs,
        lengths,
        slots,
        geom.index[order],
        geom.x[order],
        geom.y[order],
        mat,
        geom.depth[order].astype(np.float32),
        inv_fw,
        inv_fh,
        geom.origin,
        geom.image_shape,
        None if geom.core is None else geom.core[order],
    )


def _axis(px: _Pixels, shape: tuple[int, int], axis: int) -> tuple:
    """Where a pass along ``axis`` (0: x, 1: y) reads: (coord, base, stride, size, scale,
    first, span).

    A read at image coordinate p is the flat pixel ``base + clip(p)·stride``; a p
    outside [0, size) fails the inside test. Positions are image coordinates (a crop
    reads what the whole image reads); a crop's arrays start at ``first`` and span
    ``span`` pixels, and a read that leaves them gets no weight. ``coord`` (P,) is the
    pixel's own coordinate, ``scale`` (P,) float32 its pixels per scene unit.
    """
    h, w = shape
    oy, ox = px.origin
    if axis == 0:
        return px.x, (px.y - oy) * w, 1, px.image[1], px.inv_fw, ox, w
    return px.y, px.x - ox, w, px.image[0], px.inv_fh, oy, h


def _one_pass(
    src: np.ndarray,
    px: _Pixels,
    shape: tuple[int, int],
    depth_flat: np.ndarray,
    mat_flat: np.ndarray,
    tab: _Tables,
    weights: np.ndarray,
    axis: int,
    jitter_key: int | None,
    depth_slope: float | None,
    linear: bool = False,
) -> tuple[np.ndarray, int]:
    """One 1D pass over the SSS pixels.

    Parameters
    ----------
    src : (C, H·W) float32, channel-major source image
    px : sorted SSS pixels
    depth_flat : (H·W,) float32 depth; mat_flat : (H·W,) material slots
    weights : (K, n, 3J) float32 tap weights; C divides 3J (the horizontal pass
        reads the 3 lighting channels and feeds all J terms)
    axis : 0 horizontal (x), 1 vertical (y)
    jitter_key : per pass and frame hash key, or None (no jitter)
    depth_slope : bilateral tolerance (follow "slope"), or None (follow "exponential")
    linear : read between the two nearest pixels (else the nearest pixel)

    Returns
    -------
    out : (3J, P) float32, ``Σ_i w_i·sample_i`` per term and channel, sorted order
    fallback : reads with zero weight: other material, off screen, or a depth
        difference that removes them entirely (of the core pixels, for a crop)
    """
    c_in = src.shape[0]
    c_out = weights.shape[2]
    reps = c_out // c_in
    p_count = px.index.size
    n = tab.offsets.shape[1]
    coord, base, stride, size, scale, first, span = _axis(px, shape, axis)
    cropped = first != 0 or span != size
    coord_i = coord.astype(np.intp)
    coord = coord.astype(np.float32)
    base = base.astype(np.intp)
    neg_inv2tau = np.repeat((-tab.inv2tau[px.slots]).astype(np.float32), px.lengths)
    centre = np.take(src, px.index, axis=1)
    slot_depth = {s: np.where(mat_flat == s, depth_flat, np.float32(np.inf)) for s, _, _ in px.runs}
    out = np.zeros((reps, c_in, p_count), np.float32)
    fallback = 0

    def accumulate(i: int, val: np.ndarray) -> None:
        for s, a, b in px.runs:
            wi = weights[s, i].reshape(reps, c_in, 1)
            out[:, :, a:b] += wi * val[None, :, a:b]

    for i in range(n):
        if i == n // 2:
            accumulate(i, centre)
            continue
        pos = np.repeat(tab.offsets[px.slots, i].astype(np.float32), px.lengths)
        if jitter_key is not None:
            jw = tab.width[px.slots, i]
            if np.any(jw > 0):
                hx, _, _ = pcg3d(px.x, px.y, np.int64(jitter_key) * 67 + i)
                jit = (hx * np.float32(_INV_2_32)).astype(np.float32)
                jit -= np.float32(0.5)
                jit *= np.repeat(jw.astype(np.float32), px.lengths)
                pos += jit
        pos *= scale
        pos += coord
        if linear:
            p0f = np.floor(pos)
            f = pos - p0f
            p0 = p0f.astype(np.intp)
            reads = ((p0, 1.0 - f), (p0 + 1, f))
        else:
            reads = ((np.rint(pos).astype(np.intp), None),)
        val = np.zeros_like(centre)
        for p, a in reads:
            pc = np.clip(p, 0, size - 1)
            local = pc
            if cropped:
                local = pc - first
                outside = (local < 0) | (local >= span)
                local = np.clip(local, 0, span - 1)
            q = local * stride if stride != 1 else local + base
            if stride != 1:
                q += base
            # Depth of the read where it has the run's material, +inf elsewhere:
            # the weight exp(−Δz²/2τ) is then 0 for other materials.
            wz = np.empty(p_count, np.float32)
            for s, ra, rb in px.runs:
                np.take(slot_depth[s], q[ra:rb], out=wz[ra:rb])
            wz -= px.z
            if depth_slope is None:
                wz *= wz
                wz *= neg_inv2tau
                with np.errstate(invalid="ignore", over="ignore"):
                    np.exp(wz, out=wz)
            else:
                dist = np.abs(p - coord_i)
                with np.errstate(invalid="ignore"):
                    wz = (np.abs(wz) * scale <= np.float32(depth_slope) * dist).astype(np.float32)
            np.copyto(wz, 0.0, where=p != pc)
            if cropped:
                np.copyto(wz, 0.0, where=outside)
            if px.core is None:
                fallback += p_count - int(np.count_nonzero(wz))
            else:
                fallback += int(np.count_nonzero(px.core & (wz == 0)))
            if a is not None:
                wz *= a
            d = np.take(src, q, axis=1)
            d -= centre
            d *= wz
            val += d
        val += centre
        accumulate(i, val)
    return out.reshape(c_out, p_count), fallback


def _compiled_pass(
    src: np.ndarray,
    px: _Pixels,
    shape: tuple[int, int],
    depth_flat: np.ndarray,
    mat_flat: np.ndarray,
    tab: _Tables,
    weights: np.ndarray,
    axis: int,
    jitter_key: int | None,
    depth_slope: float | None,
    linear: bool = False,
    transposed: bool = False,
    rows: np.ndarray | None = None,
    out: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """:func:`_one_pass` as one compiled loop per pixel
    (:func:`core.backends.numba.separable.separable_pass`): the same float32 operations per
    read and tap, in the same order, so the same values (the exponential follow's
    ``exp`` comes from another library: within float32 rounding).

    Parameters are :func:`_one_pass`'s, but ``src`` is (H·W, C) float32, pixel-major.
    With ``transposed`` (the vertical pass, ``axis`` 1) ``src``, ``depth_flat`` and
    ``mat_flat`` are the frame's arrays transposed, and ``px.index`` indexes them
    (:class:`_Columns`). ``rows`` ((P,) int64) and ``out`` ((N, 3J) float32, zeroed):
    where each pixel's sums go (default: a new (P, 3J) array, row k for pixel k).

    Returns
    -------
    out : (N, 3J) float32 (the default: sorted order, the transpose of _one_pass's)
    fallback : as _one_pass
    """
    separable_pass = compiled_module("separable").separable_pass
    coord, base, stride, size, scale, first, span = _axis(px, shape, axis)
    if transposed:  # a column of the frame is a run of the transposed arrays
        base, stride = (px.x - px.origin[1]) * shape[0], 1
    present = np.zeros(tab.width.shape[0], bool)
    present[px.slots] = True
    p_count = px.index.size
    if out is None:
        out = np.zeros((p_count, weights.shape[2]), np.float32)
        rows = np.arange(p_count)
    core = np.ones(p_count, bool) if px.core is None else np.ascontiguousarray(px.core, bool)
    # One RGB group per call: the horizontal pass's one read feeds all J terms (c0 = 0,
    # R = J); the vertical pass reads term t's group and writes it (c0 = 3t, R = 1),
    # counting its fall-backs once.
    reps = weights.shape[2] // src.shape[1]
    fallback = 0
    # Every argument in the one form core.backends.numba.compile compiles.
    i64 = np.int64
    args = (
        np.ascontiguousarray(px.index, i64),
        np.ascontiguousarray(px.x, i64),
        np.ascontiguousarray(px.y, i64),
        np.ascontiguousarray(px.mat, np.int32),
        np.ascontiguousarray(px.z, np.float32),
        np.ascontiguousarray(coord, i64),
        np.ascontiguousarray(base, i64),
        np.ascontiguousarray(scale, np.float32),
    )
    tables = (
        np.ascontiguousarray(depth_flat, np.float32),
        np.ascontiguousarray(mat_flat, np.int32),
        np.ascontiguousarray(tab.offsets, np.float64),
        np.ascontiguousarray(tab.width, np.float64),
        np.ascontiguousarray((tab.width[present] > 0).any(axis=0)),
        np.ascontiguousarray(weights, np.float32),
        int(stride),
        int(size),
        int(first),
        int(span),
        -1 if jitter_key is None else int(jitter_key),
        -1.0 if depth_slope is None else float(depth_slope),
        (-tab.inv2tau).astype(np.float32),
        bool(linear),
        np.ascontiguousarray(rows, i64),
        out,
    )
    # One build per follow rule (core.backends.numba.separable.separable_pass).
    one_pass = separable_pass(depth_slope is None)
    src = np.ascontiguousarray(src, np.float32)
    for c0 in range(0, src.shape[1], 3):
        counted = core if c0 == 0 else np.zeros(p_count, bool)
        fallback += one_pass(src, c0, int(reps), *args, counted, *tables).sum()
    return out, int(fallback)


def apply(
    frame,
    profile: Profile,
    params: SeparableParams,
    kernels: dict[int, SlotKernel] | None = None,
    *,
    seed: int = 0,
    depth_slope: float,
    geom: Geometry | None = None,
    backend: str = "numpy",
) -> tuple[Geometry, np.ndarray, dict]:
    """Separable SSS of one frame.

    Parameters
    ----------
    frame : core.frame.Frame
    profile : Profile of the frame's materials
    params : SeparableParams
    kernels : per-slot kernels (built if None; pass them to reuse across frames)
    seed : int, jitter stream (with the frame number)
    depth_slope : float, bilateral tolerance of ``follow="slope"``: SSSParams.depth_slope,
        which holds its default (the Monte Carlo estimator follows the same rule)
    geom : Geometry from :func:`cvsss.core.geometry.geometry_of`, optional
    backend : one of core.params.BACKENDS: the passes' implementation (the
        ``separable_pass`` twin: NumPy's :func:`_one_pass`, or :func:`_compiled_pass`
        where it resolves to numba; the same values, see there)

    Returns
    -------
    geom : Geometry of the SSS pixels
    shaded : (P, 3) float64, L per SSS pixel (linear, >= 0)
    stats : dict with ``sampling_ms`` (both passes), ``reads_per_pixel`` (2·J·taps, twice that
        with the linear filter: what the method reads per pixel, its "sample count"),
        ``fallback_share`` (tap reads that fell back to the centre, of all tap reads),
        and its terms ``fallback`` and ``tap_reads`` (of a crop's core pixels only)
    """
    if kernels is None:
        kernels = build_kernels(profile, params)
    if geom is None:
        geom = geometry_of(frame, profile)
    if geom.size == 0:
        return (
            geom,
            np.zeros((0, 3)),
            {
                "sampling_ms": 0.0,
                "reads_per_pixel": 0,
                "fallback_share": 0.0,
                "fallback": 0,
                "tap_reads": 0,
            },
        )
    j = params.terms
    tab = _stack(kernels, profile.n_slots, params)
    # The sorted pixels depend on the Geometry alone (a still scene's frames share it).
    px = geom.memo("separable_pixels", lambda: _pixels(geom))
    key = None
    if params.jitter:
        key = ((int(frame.number) ^ int(seed)) & 0xFFFFFFF) * 2
    t0 = time.perf_counter()
    slope = depth_slope if params.follow == "slope" else None
    linear = params.filter == "linear"
    shaded, fallback = _two_passes(
        frame.lighting, frame.depth, geom.slots, px, geom.shape, tab, j, key, slope, linear,
        backend=backend,
    )  # fmt: skip
    sampling_ms = (time.perf_counter() - t0) * 1e3
    per_read = 2 if linear else 1
    counted = geom.size if geom.core is None else int(np.count_nonzero(geom.core))
    tap_reads = 2 * per_read * (params.taps - 1) * counted
    return (
        geom,
        shaded,
        {
            "sampling_ms": sampling_ms,
            "reads_per_pixel": 2 * j * params.taps * per_read,
            "fallback_share": fallback / tap_reads if tap_reads else 0.0,
            "fallback": fallback,
            "tap_reads": tap_reads,
        },
    )


_BIG = float(np.finfo(np.float32).max)


def _finish(terms: np.ndarray, j: int) -> np.ndarray:
    """(P, 3) float64 C-contiguous: the (3J, P) float32 ``terms`` summed over the J terms
    in float64, NaN as 0, clipped to [0, float32 max]."""
    summed = terms.reshape(j, 3, -1).sum(axis=0, dtype=np.float64)
    return np.ascontiguousarray(np.clip(np.nan_to_num(summed.T, nan=0.0, posinf=_BIG), 0.0, _BIG))


@numpy_side("separable_pass")
def _two_passes(
    lighting: np.ndarray,
    depth: np.ndarray,
    slots: np.ndarray,
    px: _Pixels,
    shape: tuple[int, int],
    tab: _Tables,
    terms: int,
    key: int | None,
    slope: float | None,
    linear: bool,
    backend: str = "numpy",
) -> tuple[np.ndarray, int]:
    """The horizontal then the vertical pass of every kernel term (NumPy).

    Parameters
    ----------
    lighting : (H, W, 3) float32, B (linear); depth : (H, W) float, scene units
    slots : (H·W,) int32 compact slots; px : the sorted SSS pixels (:func:`_pixels`)
    shape : (H, W); tab : the stacked kernels (:func:`_stack`); terms : J
    key : jitter key of the horizontal pass (the vertical one's is key + 1), or None
    slope : depth slope of the slope follow, None for the exponential follow
    linear : read between the two nearest pixels

    Returns
    -------
    shaded : (P, 3) float64, L per SSS pixel in the Geometry's order: the vertical
        pass's terms summed (:func:`_finish`), ≥ 0
    fallback : int, zero-weight reads of both passes
    """
    hgt, wid = shape
    light = np.ascontiguousarray(lighting.reshape(-1, 3).T, dtype=np.float32)
    depth_flat = depth.reshape(-1).astype(np.float32)
    first, fb1 = _one_pass(light, px, shape, depth_flat, slots, tab, tab.h, 0, key, slope, linear)
    inter = np.zeros((3 * terms, hgt * wid), np.float32)
    inter[:, px.index] = first
    vkey = None if key is None else key + 1
    second, fb2 = _one_pass(inter, px, shape, depth_flat, slots, tab, tab.v, 1, vkey, slope, linear)
    unsorted = np.empty_like(second)
    unsorted[:, px.order] = second
    return _finish(unsorted, terms), fb1 + fb2


@compiled_side("separable_pass")
def _two_passes_compiled(
    lighting, depth, slots, px, shape, tab, terms, key, slope, linear, backend="numpy"
) -> tuple[np.ndarray, int]:
    """:func:`_two_passes` with :func:`_compiled_pass`, on pixel-major images (a read's
    channels share a cache line), the vertical pass on transposed ones (its reads then
    run along memory, :class:`_Columns`): the same values. The horizontal pass writes
    its sums into the vertical pass's (transposed) image, the vertical pass into the
    Geometry's pixel order: no gathers or scatters between them; a single term is
    finished (:func:`_finish`) by a compiled pass.

    ``px.columns`` is made from ``depth`` and ``slots`` on the first call with ``px``
    (the pixels of a Geometry, whose later frames have the same depth and slots).
    """
    hgt, wid = shape
    light = np.ascontiguousarray(lighting.reshape(-1, 3), dtype=np.float32)
    depth_flat = np.ascontiguousarray(depth.reshape(-1), dtype=np.float32)
    if px.columns is None:
        px.columns = _columns(px, shape, depth_flat, slots)
    cols = px.columns
    inter = np.zeros((wid * hgt, 3 * terms), np.float32)
    _, fb1 = _compiled_pass(
        light, px, shape, depth_flat, slots, tab, tab.h, 0, key, slope, linear,
        rows=cols.index, out=inter,
    )  # fmt: skip
    vkey = None if key is None else key + 1
    second = np.zeros((px.index.size, 3 * terms), np.float32)
    _, fb2 = _compiled_pass(
        inter, cols.px, shape, cols.depth, cols.slots, tab, tab.v, 1, vkey, slope, linear,
        transposed=True, rows=cols.px.order, out=second,
    )  # fmt: skip
    if terms == 1:  # one term: _finish's conversion, NaN test and clip in one pass
        return compiled_module("separable").finish_single(second), fb1 + fb2
    return _finish(second.T, terms), fb1 + fb2
