"""Compiling every pass: each runs once on one pixel, in the argument types the
algorithm's compiled sides pass (a call in other types would compile another
specialisation).
"""

from __future__ import annotations

import numpy as np

from ...params import CONTACT_FACING
from ...sampling.qmc import DIRECTIONS
from .adaptive import spvg_counts, spvg_update
from .history import _history_pass, read_column, reproject, surface_kept, write_column
from .image import _composite_pass, _float_image_pass, row_sums
from .region import _region
from .sampling import (
    PLANAR,
    build_for,
    estimate_variance,
    pixel_sums,
    pixel_sums_serial,
    relight,
    texels,
    tile_order,
)
from .separable import finish_single, separable_pass_exp, separable_pass_slope
from .surface import surface_arrays
from .temporal import (
    MULTIPLICATIVE,
    neighbour_table,
    neighbourhood_pass,
    reuse_finish,
    reuse_finish_history,
    reuse_start,
    reuse_start_history,
)


def compile_all(pixels: int | None = None) -> None:
    """Run every pass once on one pixel: compiles it, or loads it from the disk cache.

    With ``pixels`` (the frame's, H·W) only the build of the sampling pass that
    frames of that size take (:func:`build_for`, counting every pixel as an SSS pixel
    with no samples); the other passes all the same. The two builds of the sampling
    pass are most of a cold compile's time (docs/performance.md).
    """
    builds = (pixel_sums, pixel_sums_serial)
    if pixels is not None:
        builds = (build_for(0, pixels),)
    for fn in builds:
        _compile_sampling(fn)
    tile_order(np.zeros(1, np.int64), np.zeros(1, np.int64), 1)
    f32 = np.float32
    texel = texels(  # the sampling step's first call on a Geometry
        np.ones((1, 3), f32), np.ones(1, f32), np.ones(1, f32), np.zeros((1, 3), f32),
        np.zeros(1, np.int32), True,
    )  # fmt: skip
    relight(np.ones((1, 3), f32), texel)
    estimate_variance(np.ones((1, 2)), np.zeros(1, np.int64), np.ones(1, np.int64), np.ones(1))
    depth = np.full((2, 2), 2.0, np.float32)
    for ortho in (False, True):  # the compiled depth-buffer surface (core.geometry.surface)
        surface_arrays(
            depth, np.zeros((1, 1), np.int32), False, 0, 0, 1e-3, 1e-3, 0.5, 0.5, ortho, 8.0
        )
    _region(np.ones(1), np.zeros(1, np.int64), np.ones((1, 3)), 8.0, 0.01, np.empty((4, 1, 3)))
    one, yes = np.ones(1), np.ones(1, np.bool_)
    # Through their wrappers: the passes take read-only broadcast views (_flat), a
    # specialisation of their own.
    spvg_counts(one, one, yes, one, 1e-4, 64.0, 0.25, 0.1, 8.0, 64.0, 0.01)
    spvg_update(one, one, one, yes, one, one, 0.25, 1e-4, 64.0)
    one32, at0, g3 = np.ones(1, np.float32), np.zeros(1, np.int64), np.ones((1, 3))
    _history_pass(
        one32, one32.copy(), one32.copy(), *(one32.copy() for _ in range(5)), yes.copy(),
        at0, yes, g3, g3, g3, one, np.ones(1, np.int32), 2, 1.0, 0.75, 0.1875, 0.25, 1e-4,
        64.0, 1e150, 1e-4, 1e-6, np.empty(1), np.empty(1), yes.copy(),
    )  # fmt: skip
    rows, at = np.ones((1, 3), np.float32), np.zeros(1, np.int64)
    _composite_pass(rows, rows, rows, at, np.ones((1, 3)), one, True, 1.0, rows.copy(), rows.copy())
    _float_image_pass(np.ones((1, 3)), at, 0.0, 1.0, rows.copy())
    row_sums(np.ones((1, 3)))
    plane, mask = np.ones((1, 1), np.float32), np.ones((1, 1), np.bool_)
    for dtype in (np.float16, np.float32):  # the history's storage
        for slots in (np.int32, np.int64):  # a Frame's slots, or wider ones
            key = np.zeros((1, 1), slots)
            block = np.zeros((2, 1, 1), dtype)
            reproject(None, plane, key, plane, key, 0.1, block, np.ones(2, bool), mask, mask)
    for slots in (np.int32, np.int64):  # a still camera's reprojection in place
        surface_kept(plane, np.zeros((1, 1), slots), plane, np.zeros((1, 1), slots), 0.1)
    read_column(one32, at, 1.0, g3, 0)
    write_column(g3, 0, at, 1.0, one32.copy())
    # The separable passes (the separable method, the temporal proxy) and the temporal
    # reuse's neighbourhood and per-pixel steps, in the argument types
    # core.separable.apply and core.mc.temporal pass.
    pix = (at, at, at, np.ones(1, np.int32), one32, at, at, one32)
    tables = (np.ones(1, f32), np.ones(1, np.int32), np.zeros((2, 3)), np.zeros((2, 3)))
    for build in (separable_pass_slope, separable_pass_exp):
        build(
            np.ones((1, 3), f32), 0, 1, *pix, yes, *tables, np.zeros(3, np.bool_),
            np.ones((2, 3, 3), f32), 1, 1, 0, 1, -1, 2.0, np.ones(2, f32), True, at,
            np.zeros((1, 3), f32),
        )  # fmt: skip
    finish_single(np.ones((1, 3), f32))
    table = neighbour_table(at, np.ones(1, np.int32), at, 1, 1)
    neighbourhood_pass(g3, yes, table, g3.copy(), g3.copy())
    rgb = [np.ones((1, 3)) for _ in range(8)]
    reuse_start(*rgb[:2], one, rgb[2], one, yes, *rgb[3:5], np.ones(3), MULTIPLICATIVE, 0.2, 0.3,
                *rgb[5:7], one.copy())  # fmt: skip
    reuse_finish(*rgb[:4], one, yes, *rgb[4:6], 2.0, one, 1e-12, MULTIPLICATIVE, True, 2.0, 0.1,
                 *rgb[6:8], one.copy())  # fmt: skip
    # The same on a float32 history's buffers (core.mc.temporal._reuse_compiled).
    bufs = tuple(one32.copy() for _ in range(3))
    reuse_start_history(*rgb[:2], one, rgb[2], yes, at, one32.copy(), bufs, bufs, np.ones(3),
                        MULTIPLICATIVE, 0.2, 0.3, one, table, *rgb[3:5], one.copy(), one.copy())  # fmt: skip
    reuse_finish_history(*rgb[:3], one, yes, at, bufs, one32.copy(), table, 2.0, one, 1e-12,
                         MULTIPLICATIVE, 2.0, 0.1, rgb[5], one.copy())  # fmt: skip


def _compile_sampling(fn) -> None:
    f32 = np.float32
    one = np.ones(1)
    g3 = np.full((1, 3), 0.5)
    fn(
        np.zeros(1, np.int64),
        np.zeros(1, np.int64),
        np.ones(1, np.int64),
        np.zeros(1, np.int64),
        np.zeros(1, np.int64),
        g3,
        np.full(1, 1.5),
        np.full((1, 3), 0.1),
        g3,
        np.ones(1, np.int32),
        one,
        one,
        one,
        np.zeros(1, np.int64),
        np.zeros(1, np.bool_),
        np.ones(1, np.bool_),
        np.uint64(0),
        np.ones((2, 3)),
        np.ones(8, f32),
        np.ones(10, f32),
        f32(16.0),
        DIRECTIONS.reshape(-1),
        np.ones((3, 2), f32),
        np.ones((3, 2), f32),
        np.ones(10, f32),
        np.ones(120, f32),
        f32(1.0),
        False,
        f32(1.0),
        np.zeros(2, np.bool_),  # the mirror, per slot
        np.zeros((1, 3), f32),
        False,
        f32(1.0),
        f32(0.0),
        f32(CONTACT_FACING),
        1,
        1,
        f32(1.0),
        f32(1.0),
        0,
        0,
        f32(2.0),
        PLANAR,
        f32(1.0),
        f32(1.0),
        f32(1.0),
        f32(0.0),
        f32(0.0),
        1.0,
        1.0,
        0.0,
        0.0,
        True,
        np.zeros((1, 3)),
        False,
        1,
    )
