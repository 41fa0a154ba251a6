"""The history's compiled passes: the whole history step, its reprojection and its
reads and writes (the numba sides of the ``history_step``, ``reproject``,
``history_read`` and ``history_write`` twins, :mod:`core.mc.history` and
:mod:`core.mc.update`).
"""

from __future__ import annotations

import numba
import numpy as np

from .adaptive import _spvg_constants, _spvg_step
from .common import _F64_MAX, _R0, _R1, _R2, _bounded, _finite, _stored

CV_MODES = {"none": 0, "constant": 1, "online": 2}


def history_step(
    buffers, index, valid, distant, gamma, b, weight, counts, cv, constants, cv_history=None
):
    """The history step of ``core.mc.update`` in one parallel pass over
    the SSS pixels, on a float32 history (stored unscaled): the tracked luminance, the
    online control variate's α and EMCM step (Alg. 2, Eq. 33), Eq. 5–7 and the stores
    into the history's buffers at ``index``, in place. The same float64 operations in
    the same order as the NumPy step, and the same float32 stores
    (tests/core/test_backend.py).

    Parameters
    ----------
    buffers : (mu, var, mbar), the History's (H, W) float32 buffers (written in place)
    index : (P,) int64, flat pixel index; valid : (P,) bool, the history was valid
    distant, gamma, b : (P, 3) float64, the distant estimate, γ and B
    weight : (P,) float64, Subsurface Weight; counts : (P,) int, m_t
    cv : {"none", "constant", "online"}, the method's control variate
    constants : (exposure, η, σ0², n_init, limit, ε_α, η_cv) floats: the exposure of the
        tracked luminances, SPVG's η, σ0² and no-history count, the bound on the
        tracked values (±limit) and the control variate's ε_α and η_cv
    cv_history : with ``cv="online"``: ((sxx, sxy, syy, zf, zg), cv_valid), the
        History's (H, W) float32 J buffers (written in place) and its (H, W) bool
        mask of valid J (read)

    Returns
    -------
    var : (P,) float64, σ² at t where m_t > 0, else 0
    new_valid : (H, W) bool, the pixels with m_t > 0
    alpha : (P,) float64, α where m_t > 0 (0 without a control variate, 1 constant),
        else 0
    """
    exposure, eta, s0, n_init, limit, eps_alpha, eta_cv = constants
    mu, var, mbar = buffers
    h, w = mu.shape
    n = index.shape[0]
    out = np.empty(n)
    alpha = np.empty(n)
    new_valid = np.zeros(h * w, np.bool_)
    if cv == "online":
        j_buffers, cv_valid = cv_history
        j_flat = tuple(x.reshape(-1) for x in j_buffers)
        cv_valid = np.ascontiguousarray(cv_valid).reshape(-1)
    else:  # not read
        j_flat = (np.empty(0, np.float32),) * 5
        cv_valid = np.empty(0, np.bool_)
    _history_pass(
        mu.reshape(-1),
        var.reshape(-1),
        mbar.reshape(-1),
        *j_flat,
        cv_valid,
        index,
        valid,
        np.ascontiguousarray(distant, dtype=np.float64),
        np.ascontiguousarray(gamma, dtype=np.float64),
        np.ascontiguousarray(b, dtype=np.float64),
        np.ascontiguousarray(weight, dtype=np.float64),
        np.ascontiguousarray(counts),
        CV_MODES[cv],
        float(exposure),
        *_spvg_constants(eta, s0, n_init),
        float(limit),
        float(eps_alpha),
        float(eta_cv),
        out,
        alpha,
        new_valid,
    )
    return out, new_valid.reshape(h, w), alpha


@numba.njit(inline="always", error_model="numpy")
def _cv_alpha(s_xy, s_yy, f, g, eps_alpha):
    """core.mc.control_variates.cv_coefficient of one pixel (float64)."""
    big = _F64_MAX
    num = s_xy + eps_alpha
    den = s_yy + eps_alpha
    alpha = num / den if den > 0 else 1.0
    upper = 1.0
    if g > 0:
        q = (f + g) / g
        upper = q if (q >= 0.0 or np.isnan(q)) else 0.0  # np.maximum(q, 0.0)
    upper = _finite(upper, 1.0, big, -big)
    alpha = _finite(alpha, 1.0, big, 0.0)
    alpha = alpha if alpha > 0.0 else 0.0  # np.clip(alpha, 0.0, upper)
    return alpha if alpha < upper else upper


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _history_pass(
    mu,
    var,
    mbar,
    sxx,
    sxy,
    syy,
    zf,
    zg,
    cv_valid,
    index,
    valid,
    distant,
    gamma,
    b,
    weight,
    counts,
    cv_mode,
    exposure,
    keep,
    spread,
    eta,
    s0,
    n_init,
    limit,
    eps_alpha,
    eta_cv,
    out,
    alpha_out,
    new_valid,
):
    keep_cv = 1.0 - eta_cv
    spread_cv = eta_cv * (1.0 - eta_cv)
    for i in numba.prange(index.shape[0]):
        # f̄ = (Î·exposure)·Rec.709 and G = ((γ·B)·exposure)·Rec.709, times the weight.
        f = (
            (distant[i, 0] * exposure) * _R0
            + (distant[i, 1] * exposure) * _R1
            + (distant[i, 2] * exposure) * _R2
        )
        g = (
            ((gamma[i, 0] * b[i, 0]) * exposure) * _R0
            + ((gamma[i, 1] * b[i, 1]) * exposure) * _R1
            + ((gamma[i, 2] * b[i, 2]) * exposure) * _R2
        )
        f = _bounded(f * weight[i], limit)
        g = _bounded(g * weight[i], limit)
        j = index[i]
        m = counts[i]
        if cv_mode == 2:
            # α from Σ at t − 1 (Alg. 2), then one EMCM step (Eq. 33) of Z = (f̄, G);
            # Σ starts at 0 and ζ at Z where J is not valid (core.mc.update._online_cv).
            jv = cv_valid[j] and valid[i]
            c_xx = np.float64(sxx[j]) if jv else 0.0
            c_xy = np.float64(sxy[j]) if jv else 0.0
            c_yy = np.float64(syy[j]) if jv else 0.0
            z_f = np.float64(zf[j]) if jv else f
            z_g = np.float64(zg[j]) if jv else g
            a = _cv_alpha(c_xy, c_yy, f, g, eps_alpha)
            d_f = f - z_f
            d_g = g - z_g
            sxx[j] = _stored(keep_cv * c_xx + spread_cv * d_f * d_f if jv else 0.0)
            sxy[j] = _stored(keep_cv * c_xy + spread_cv * d_f * d_g if jv else 0.0)
            syy[j] = _stored(keep_cv * c_yy + spread_cv * d_g * d_g if jv else 0.0)
            zf[j] = _stored(keep_cv * z_f + eta_cv * f if jv else f)
            zg[j] = _stored(keep_cv * z_g + eta_cv * g if jv else g)
            s = f - a * g
        elif cv_mode == 1:
            a = 1.0
            s = f - 1.0 * g
        else:
            a = 0.0
            s = f
        mu_t, var_t, mbar_t = _spvg_step(
            s,
            valid[i],
            np.float64(mu[j]),
            np.float64(var[j]),
            np.float64(mbar[j]),
            np.float64(m),
            keep,
            spread,
            eta,
            s0,
            n_init,
        )
        mu[j] = _stored(mu_t)
        var[j] = _stored(var_t)
        mbar[j] = _stored(mbar_t)
        out[i] = var_t if m > 0 else 0.0
        alpha_out[i] = a if m > 0 else 0.0
        new_valid[j] = m > 0


_BITS = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}


#: Pixels per parallel task of the reprojection: the task's source map is kept for its
#: buffers, each copied as one run (a few streams at a time, not one per buffer).
_REPROJECT_TASK = 4096


def reproject(
    motion, depth, material, prev_depth, prev_material, tolerance, block, reset, valid, cv_valid
):
    """The reprojected history in one parallel pass: each pixel's source, on-screen flag
    and surface match, then the buffers and masks fetched from the source.

    :meth:`core.mc.history.History.reproject`'s arithmetic (float64 positions, ``rint``
    of the clipped position, the relative depth test) per pixel; a fetched value is the
    source's bits where kept, zero elsewhere.

    Parameters
    ----------
    motion : (H, W, 2) float32 or None (static)
    depth, prev_depth : (H, W) float32; material, prev_material : (H, W) int
    tolerance : float, relative depth change still accepted
    block : (F, H, W) float16 or float32, the history's buffers, one per row
    reset : (F,) bool, the buffer is kept only where the surface is the same (else
        wherever the source is on screen)
    valid, cv_valid : (H, W) bool, kept where the surface is the same

    Returns
    -------
    block : (F, H, W), valid, cv_valid : (H, W) bool, new arrays
    """
    h, w = depth.shape
    n = h * w
    flow = np.zeros((0, 2), np.float32) if motion is None else motion.reshape(n, 2)
    slots = _slot_dtype(material, prev_material)
    bits = _BITS[block.dtype.itemsize]
    out = np.empty(block.shape, block.dtype)
    valid_out = np.empty((h, w), np.bool_)
    cv_out = np.empty((h, w), np.bool_)
    _reproject_pass(
        np.ascontiguousarray(flow),
        motion is not None,
        h,
        w,
        np.ascontiguousarray(depth).reshape(-1),
        np.ascontiguousarray(material, slots).reshape(-1),
        np.ascontiguousarray(prev_depth).reshape(-1),
        np.ascontiguousarray(prev_material, slots).reshape(-1),
        float(tolerance),
        np.ascontiguousarray(block).reshape(block.shape[0], n).view(bits),
        np.ascontiguousarray(reset, np.bool_),
        np.ascontiguousarray(valid).reshape(-1),
        np.ascontiguousarray(cv_valid).reshape(-1),
        out.reshape(block.shape[0], n).view(bits),
        valid_out.reshape(-1),
        cv_out.reshape(-1),
    )
    return out, valid_out, cv_out


def _slot_dtype(material, prev_material):
    """Slots compared as int32 where both are (a Frame's and a History's are), else int64."""
    narrow = material.dtype == np.int32 and prev_material.dtype == np.int32
    return np.int32 if narrow else np.int64


@numba.njit(cache=True, inline="always", error_model="numpy")
def _same_surface(depth, material, prev_depth, prev_material, i, s, tol):
    """Pixel i's surface is the one its source s held (core.mc.history._same_surface:
    the same slot, the float64 relative depth test)."""
    prev = np.float64(prev_depth[s])
    cur = np.float64(depth[i])
    return prev_material[s] == material[i] and abs(prev - cur) <= tol * cur


def surface_kept(depth, material, prev_depth, prev_material, tolerance):
    """(H, W) bool: each pixel's surface is the one it held, the reprojection's test
    with every pixel its own source (:func:`_same_surface`), in one parallel pass.

    Parameters
    ----------
    depth, prev_depth : (H, W) float32; material, prev_material : (H, W) int
    tolerance : float, relative depth change still accepted
    """
    slots = _slot_dtype(material, prev_material)
    out = np.empty(depth.shape, np.bool_)
    _surface_kept_pass(
        np.ascontiguousarray(depth).reshape(-1),
        np.ascontiguousarray(material, slots).reshape(-1),
        np.ascontiguousarray(prev_depth).reshape(-1),
        np.ascontiguousarray(prev_material, slots).reshape(-1),
        float(tolerance),
        out.reshape(-1),
    )
    return out


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _surface_kept_pass(depth, material, prev_depth, prev_material, tol, out):
    for i in numba.prange(depth.shape[0]):
        out[i] = _same_surface(depth, material, prev_depth, prev_material, i, i, tol)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _source(i, flow, has_motion, w, h):
    """(flat source pixel, on screen) of pixel i moved by its motion vector."""
    if not has_motion:
        return np.int64(i), True
    y = i // w
    fx = np.float64(i - y * w) + np.float64(flow[i, 0])
    fy = np.float64(y) + np.float64(flow[i, 1])
    ok = np.isfinite(fx) and np.isfinite(fy)
    if not ok:
        fx = -1.0
        fy = -1.0
    px = np.int64(np.rint(min(max(fx, -1.0), np.float64(w))))
    py = np.int64(np.rint(min(max(fy, -1.0), np.float64(h))))
    ok = ok and px >= 0 and px < w and py >= 0 and py < h
    return (py * w + px if ok else np.int64(0)), ok


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _reproject_pass(
    flow, has_motion, h, w, depth, material, prev_depth, prev_material, tol, block, reset,
    valid, cv_valid, out, valid_out, cv_out,
):  # fmt: skip
    n = depth.shape[0]
    n_tasks = (n + _REPROJECT_TASK - 1) // _REPROJECT_TASK
    for t in numba.prange(n_tasks):
        start = t * _REPROJECT_TASK
        end = min(n, start + _REPROJECT_TASK)
        src = np.empty(end - start, np.int64)
        inside = np.empty(end - start, np.bool_)
        same = np.empty(end - start, np.bool_)
        for i in range(start, end):
            s, ok = _source(i, flow, has_motion, w, h)
            match = ok and _same_surface(depth, material, prev_depth, prev_material, i, s, tol)
            src[i - start] = s
            inside[i - start] = ok
            same[i - start] = match
            valid_out[i] = valid[s] if match else False
            cv_out[i] = cv_valid[s] if match else False
        for f in range(block.shape[0]):
            keep = same if reset[f] else inside
            if has_motion:
                for i in range(start, end):
                    out[f, i] = block[f, src[i - start]] if keep[i - start] else 0
            else:  # each pixel its own source: a masked copy, vectorised
                for i in range(start, end):
                    out[f, i] = block[f, i] if keep[i - start] else 0


# -- the history's reads and writes (core.mc.history.History.read_columns) -------------
@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def read_column(buf, index, scale, out, col):
    """``out[:, col] = buf[index] / scale`` in float64 (History.read of a float32 buffer:
    the same values).

    Parameters
    ----------
    buf : (H·W,) float32, a history buffer (stored units); index : (P,) int64 flat pixels
    scale : float, stored value = true value × scale; out : (P, k) float64, written
    col : int, the column of ``out`` to write
    """
    for k in numba.prange(index.shape[0]):
        v = np.float64(buf[index[k]])
        if scale != 1.0:
            v = v / scale
        out[k, col] = v


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def write_column(values, col, index, scale, buf):
    """``buf[index] = values[:, col]`` as History.write stores a float32 buffer: times
    ``scale``, then :func:`_stored` (clipped to ±float32 max, ±inf too, NaN stored as 0,
    rounded to float32).

    Parameters
    ----------
    values : (P, k) float64, true units; col : int; index : (P,) int64 flat pixels
    scale : float; buf : (H·W,) float32, written
    """
    for k in numba.prange(index.shape[0]):
        v = values[k, col]
        if scale != 1.0:
            v = v * scale
        buf[index[k]] = _stored(v)
