"""The temporal reuse's neighbourhood statistics and per-pixel steps, compiled (the
numba sides of the ``neighbourhood`` and ``reuse_step`` twins, :mod:`core.mc.temporal`).
"""

from __future__ import annotations

import numba
import numpy as np

from .common import _R0, _R1, _R2


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def neighbour_table(index, mat, where, w, h):
    """Each pixel's 3×3 neighbours of the same slot, for :func:`neighbourhood_pass`.

    Parameters
    ----------
    index : (P,) int64 flat pixel; mat : (P,) int32 slot; where : (H·W,) int64, the
        Geometry pixel at each frame pixel (−1: none); w, h : int, the frame's size

    Returns
    -------
    (P, 9) int32, the Geometry pixel of each neighbour, row by row from (−1, −1) to
    (+1, +1) (the pixel itself fifth); −1 off the frame, on no SSS pixel or on
    another slot
    """
    n_pix = index.shape[0]
    out = np.empty((n_pix, 9), np.int32)
    for k in numba.prange(n_pix):
        y = index[k] // w
        x = index[k] - y * w
        e = 0
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                xx = x + dx
                yy = y + dy
                j = -1
                if xx >= 0 and xx < w and yy >= 0 and yy < h:
                    j = where[yy * w + xx]
                    if j >= 0 and mat[j] != mat[k]:
                        j = -1
                out[k, e] = j
                e += 1
    return out


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def neighbourhood_pass(values, active, table, mean, std):
    """Mean and standard deviation over each pixel's 3×3 neighbours of the same slot
    holding a value (:func:`core.mc.temporal.neighbourhood`, its float64 operations in
    its order: a neighbour without a value adds 0).

    Parameters
    ----------
    values : (P, 3) float64; active : (P,) bool
    table : (P, 9) int32, :func:`neighbour_table` (a still scene's Geometry keeps it)
    mean, std : (P, 3) float64, written
    """
    n_pix = table.shape[0]
    for k in numba.prange(n_pix):
        t0 = t1 = t2 = 0.0
        q0 = q1 = q2 = 0.0
        count = 0.0
        for e in range(9):
            j = table[k, e]
            v0 = v1 = v2 = 0.0
            ok = False
            if j >= 0:
                uj = np.uint64(j)
                if active[uj] and not np.isnan(values[uj, 0]):
                    ok = True
                    v0 = values[uj, 0]
                    v1 = values[uj, 1]
                    v2 = values[uj, 2]
            t0 += v0
            t1 += v1
            t2 += v2
            q0 += v0 * v0
            q1 += v1 * v1
            q2 += v2 * v2
            count += 1.0 if ok else 0.0
        nn = max(count, 1.0)
        m0 = t0 / nn
        m1 = t1 / nn
        m2 = t2 / nn
        mean[k, 0] = m0
        mean[k, 1] = m1
        mean[k, 2] = m2
        std[k, 0] = np.sqrt(max(q0 / nn - m0 * m0, 0.0))
        std[k, 1] = np.sqrt(max(q1 / nn - m1 * m1, 0.0))
        std[k, 2] = np.sqrt(max(q2 / nn - m2 * m2, 0.0))


# -- the temporal reuse's per-pixel arithmetic (core.mc.temporal.reuse) ----------------
#: Temporal modes of the reuse kernels.
PLAIN, SUBTRACTIVE, MULTIPLICATIVE = 0, 1, 2


@numba.njit(inline="always", error_model="numpy")
def _pos(x):
    """np.maximum(x, 0.0) of one value (NaN stays NaN)."""
    return x if (np.isnan(x) or x > 0.0) else 0.0


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def reuse_start(
    distant, control, alpha, proxy, n_prev, active, ctl_prev, prox_prev, eps, mode, switch,
    tolerance, shift, value, n_out,
):  # fmt: skip
    """The reuse's first per-pixel step (:func:`core.mc.temporal.reuse` up to the
    neighbourhood clamp): the shift and the value accumulated, and the frame count cut
    by the rectification δ, in float64 with reuse's operations (``log`` and ``exp`` are
    libm's: within an ulp of NumPy's).

    Parameters
    ----------
    distant, control : (P, 3) float64; alpha : (P,) float64; proxy : (P, 3) float64
        (read in the multiplicative mode only); n_prev : (P,) float64, the history's frame
        count; active : (P,) bool; ctl_prev, prox_prev : (P, 3) float64, the history's
        control and proxy (read in the guided modes); eps : (3,) float64
    mode : PLAIN, SUBTRACTIVE or MULTIPLICATIVE; switch : float, SWITCH_WEIGHT;
        tolerance : float, τ
    shift, value : (P, 3) float64, written (shift: 0 in the plain mode)
    n_out : (P,) float64, written: the frame count after the cut
    """
    for k in numba.prange(distant.shape[0]):
        worst = -np.inf
        nan = False
        for c in range(3):
            e = eps[c]
            if mode == MULTIPLICATIVE:
                sh = _pos(proxy[k, c]) + e
                value[k, c] = distant[k, c] / sh
            elif mode == SUBTRACTIVE:
                sh = alpha[k] * control[k, c]
                value[k, c] = distant[k, c] - sh
            else:
                sh = 0.0
                value[k, c] = distant[k, c]
            shift[k, c] = sh
            if mode != PLAIN:
                d_ctl = np.log(control[k, c] + e) - np.log(_pos(ctl_prev[k, c]) + e)
                if mode == MULTIPLICATIVE:
                    d_prox = np.log(sh) - np.log(_pos(prox_prev[k, c]) + e)
                    delta = abs(d_prox - d_ctl) + switch * abs(d_ctl)
                else:
                    delta = abs(d_ctl)
                if np.isnan(delta):
                    nan = True
                elif delta > worst:
                    worst = delta
        n = n_prev[k] if active[k] else 0.0
        if mode != PLAIN:
            # NumPy's max over channels propagates NaN; nan_to_num makes it +inf.
            d = np.inf if nan else worst
            r = d / tolerance
            n = n * np.exp(-(r * r))
        n_out[k] = n


@numba.njit(inline="always", error_model="numpy")
def _clip(x, lo, hi):
    """np.clip of one value: NaN where any of the three is NaN."""
    if np.isnan(x) or np.isnan(lo) or np.isnan(hi):
        return np.nan
    return min(max(x, lo), hi)


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def reuse_finish(
    distant, prev, value, shift, n_in, active, mean, std, clamp, sigma, floor, mode,
    use_noise, noise_sigmas, min_weight, acc, out, n_new,
):  # fmt: skip
    """The reuse's last per-pixel step (:func:`core.mc.temporal.reuse` from the clamp on):
    the clamped history, the noise test's cut, λ, the accumulation and the output.

    Parameters
    ----------
    distant, prev, value, shift : (P, 3) float64 (prev: the history's accumulation)
    n_in : (P,) float64, the frame count after :func:`reuse_start`; active : (P,) bool
    mean, std : (P, 3) float64, the neighbourhood of ``value`` (with ``clamp`` finite)
    clamp : float, k (inf: no clamp); sigma : (P,) float64, the pooled noise (with
        ``use_noise``); floor : float, its lower bound 1e-12·(scale·Y)
    mode : PLAIN, SUBTRACTIVE or MULTIPLICATIVE; use_noise : bool (guided modes with a
        noise estimate); noise_sigmas : float; min_weight : float, λ_min
    acc, out : (P, 3) float64, written; n_new : (P,) float64, written
    """
    finite_clamp = np.isfinite(clamp)
    for k in numba.prange(distant.shape[0]):
        p0 = prev[k, 0]
        p1 = prev[k, 1]
        p2 = prev[k, 2]
        if finite_clamp:
            p0 = _clip(p0, mean[k, 0] - clamp * std[k, 0], mean[k, 0] + clamp * std[k, 0])
            p1 = _clip(p1, mean[k, 1] - clamp * std[k, 1], mean[k, 1] + clamp * std[k, 1])
            p2 = _clip(p2, mean[k, 2] - clamp * std[k, 2], mean[k, 2] + clamp * std[k, 2])
        n = n_in[k]
        if use_noise:
            if mode == MULTIPLICATIVE:
                g0 = p0 * shift[k, 0] - distant[k, 0]
                g1 = p1 * shift[k, 1] - distant[k, 1]
                g2 = p2 * shift[k, 2] - distant[k, 2]
            else:
                g0 = p0 + shift[k, 0] - distant[k, 0]
                g1 = p1 + shift[k, 1] - distant[k, 1]
                g2 = p2 + shift[k, 2] - distant[k, 2]
            gap = abs(g0 * _R0 + g1 * _R1 + g2 * _R2)
            z = gap / max(sigma[k], floor)
            if np.isnan(z):
                z = np.inf
            m = max(z - noise_sigmas, 0.0)
            n = n * np.exp(-0.5 * (m * m))
        r = 1.0 / (n + 1.0)
        lam = r if (np.isnan(r) or r > min_weight) else min_weight
        on = active[k]
        ps = (p0, p1, p2)
        for c in range(3):
            a = (1.0 - lam) * ps[c] + lam * value[k, c] if on else value[k, c]
            acc[k, c] = a
            if not on:
                o = distant[k, c]
            elif mode == MULTIPLICATIVE:
                o = a * shift[k, c]
            elif mode == SUBTRACTIVE:
                o = a + shift[k, c]
            else:
                o = a
            out[k, c] = o
        n_new[k] = n + 1.0 if on else 0.0
