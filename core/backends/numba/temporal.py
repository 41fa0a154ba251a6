"""The temporal reuse's neighbourhood statistics and per-pixel steps, compiled (the
numba sides of the ``neighbourhood`` and ``reuse_step`` twins, :mod:`core.mc.temporal`).
"""

from __future__ import annotations

import numba
import numpy as np

from .common import _R0, _R1, _R2, _stored


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


@numba.njit(inline="always", error_model="numpy")
def _neighbour(values, active, table, k, e):
    """Whether neighbour ``e`` of pixel k (its ``table`` entry) holds a value (in the
    frame, active, not NaN), and that value's three channels (zeros where not)."""
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
    return ok, v0, v1, v2


@numba.njit(inline="always", error_model="numpy")
def _neighbours(values, active, table, k):
    """Mean and standard deviation per channel of pixel k's neighbours holding a value
    (:func:`neighbourhood_pass` of one pixel): (m0, m1, m2, s0, s1, s2)."""
    t0 = t1 = t2 = 0.0
    q0 = q1 = q2 = 0.0
    count = 0.0
    for e in range(9):
        ok, v0, v1, v2 = _neighbour(values, active, table, k, e)
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
    s0 = np.sqrt(max(q0 / nn - m0 * m0, 0.0))
    s1 = np.sqrt(max(q1 / nn - m1 * m1, 0.0))
    s2 = np.sqrt(max(q2 / nn - m2 * m2, 0.0))
    return m0, m1, m2, s0, s1, s2


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
    for k in numba.prange(table.shape[0]):
        m0, m1, m2, s0, s1, s2 = _neighbours(values, active, table, k)
        mean[k, 0] = m0
        mean[k, 1] = m1
        mean[k, 2] = m2
        std[k, 0] = s0
        std[k, 1] = s1
        std[k, 2] = s2


# -- the temporal reuse's per-pixel arithmetic (core.mc.temporal.reuse) ----------------
#: Temporal modes of the reuse kernels.
PLAIN, SUBTRACTIVE, MULTIPLICATIVE = 0, 1, 2


@numba.njit(inline="always", error_model="numpy")
def _pos(x):
    """np.maximum(x, 0.0) of one value (NaN stays NaN)."""
    return x if (np.isnan(x) or x > 0.0) else 0.0


@numba.njit(inline="always", error_model="numpy")
def _start_channel(d, ctl, a, prox, ctl_prev, prox_prev, e, mode, switch):
    """One channel of :func:`reuse_start`: (shift, value, δ); δ is 0 in the plain mode
    (``ctl_prev`` and ``prox_prev`` are read in the guided modes only)."""
    if mode == MULTIPLICATIVE:
        sh = _pos(prox) + e
        val = d / sh
    elif mode == SUBTRACTIVE:
        sh = a * ctl
        val = d - sh
    else:
        sh = 0.0
        val = d
    delta = 0.0
    if mode != PLAIN:
        ctl_ratio = (ctl + e) / (_pos(ctl_prev) + e)
        d_ctl = np.log(ctl_ratio)
        if mode == MULTIPLICATIVE:
            prox_ratio = sh / (_pos(prox_prev) + e)
            delta = abs(np.log(prox_ratio / ctl_ratio)) + switch * abs(d_ctl)
        else:
            delta = abs(d_ctl)
    return sh, val, delta


@numba.njit(inline="always", error_model="numpy")
def _cut(n, d0, d1, d2, mode, tolerance):
    """The frame count ``n`` cut by the largest of the channels' δ (NumPy's max over
    channels propagates NaN; nan_to_num makes it +inf)."""
    if mode == PLAIN:
        return n
    worst = -np.inf
    nan = False
    for delta in (d0, d1, d2):
        if np.isnan(delta):
            nan = True
        elif delta > worst:
            worst = delta
    d = np.inf if nan else worst
    r = d / tolerance
    return n * np.exp(-(r * r))


@numba.njit(inline="always", error_model="numpy")
def _start_columns(k, c, distant, control, inputs, mode, switch, shift, value):
    """Channel c of pixel k of :func:`reuse_start` (shift and value written): its δ.
    ``inputs``: (alpha, proxy, ctl_prev, prox_prev, eps) as reuse_start takes them."""
    alpha, proxy, ctl_prev, prox_prev, eps = inputs
    sh, val, delta = _start_channel(
        distant[k, c], control[k, c], alpha[k],
        proxy[k, c] if mode == MULTIPLICATIVE else 0.0,
        ctl_prev[k, c] if mode != PLAIN else 0.0,
        prox_prev[k, c] if mode == MULTIPLICATIVE else 0.0, eps[c], mode, switch,
    )  # fmt: skip
    shift[k, c] = sh
    value[k, c] = val
    return delta


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
        a = (alpha, proxy, ctl_prev, prox_prev, eps)
        d0 = _start_columns(k, 0, distant, control, a, mode, switch, shift, value)
        d1 = _start_columns(k, 1, distant, control, a, mode, switch, shift, value)
        d2 = _start_columns(k, 2, distant, control, a, mode, switch, shift, value)
        n_out[k] = _cut(n_prev[k] if active[k] else 0.0, d0, d1, d2, mode, tolerance)


@numba.njit(inline="always", error_model="numpy")
def _clip(x, lo, hi):
    """np.clip of one value: NaN where any of the three is NaN."""
    if np.isnan(x) or np.isnan(lo) or np.isnan(hi):
        return np.nan
    return min(max(x, lo), hi)


@numba.njit(inline="always", error_model="numpy")
def _finish_cut(n, p0, p1, p2, s0, s1, s2, d0, d1, d2, sigma, floor, mode, noise_sigmas):
    """The noise test's cut of the frame count ``n``: the history's prediction
    (clamped accumulation p, shift s) against the estimate d in units of ``sigma``."""
    return n * np.exp(
        _noise_exponent(p0, p1, p2, s0, s1, s2, d0, d1, d2, sigma, floor, mode, noise_sigmas)
    )


@numba.njit(inline="always", error_model="numpy")
def _noise_exponent(p0, p1, p2, s0, s1, s2, d0, d1, d2, sigma, floor, mode, noise_sigmas):
    """The exponent of :func:`_finish_cut`'s factor, −(z − NOISE_SIGMAS)₊²/2."""
    if mode == MULTIPLICATIVE:
        g0 = p0 * s0 - d0
        g1 = p1 * s1 - d1
        g2 = p2 * s2 - d2
    else:
        g0 = p0 + s0 - d0
        g1 = p1 + s1 - d1
        g2 = p2 + s2 - d2
    gap = abs(g0 * _R0 + g1 * _R1 + g2 * _R2)
    z = gap / max(sigma, floor)
    if np.isnan(z):
        z = np.inf
    m = max(z - noise_sigmas, 0.0)
    return -0.5 * (m * m)


@numba.njit(inline="always", error_model="numpy")
def _weight(n, min_weight):
    """λ = max(λ_min, 1/(n + 1)) (np.maximum: NaN stays NaN)."""
    r = 1.0 / (n + 1.0)
    return r if (np.isnan(r) or r > min_weight) else min_weight


@numba.njit(inline="always", error_model="numpy")
def _output(a, shift, d, on, mode):
    """The reuse's output of one channel: accumulation a with the shift, or the estimate
    d where the pixel is inactive."""
    if not on:
        return d
    if mode == MULTIPLICATIVE:
        return a * shift
    if mode == SUBTRACTIVE:
        return a + shift
    return a


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
            n = _finish_cut(
                n, p0, p1, p2, shift[k, 0], shift[k, 1], shift[k, 2], distant[k, 0],
                distant[k, 1], distant[k, 2], sigma[k], floor, mode, noise_sigmas,
            )  # fmt: skip
        lam = _weight(n, min_weight)
        on = active[k]
        ps = (p0, p1, p2)
        for c in range(3):
            a = (1.0 - lam) * ps[c] + lam * value[k, c] if on else value[k, c]
            acc[k, c] = a
            out[k, c] = _output(a, shift[k, c], distant[k, c], on, mode)
        n_new[k] = n + 1.0 if on else 0.0


# -- the same, reading and writing a float32 history in place ---------------------------
@numba.njit(inline="always", error_model="numpy")
def _pooled_sigma(noise, active, table, k):
    """core.mc.temporal._pooled_sigma of pixel k: the noise's variance (NaN as 0) pooled
    over the neighbours where finite (:func:`_neighbours` of its one channel), its
    square root; inf where the pixel's own is not finite."""
    total = 0.0
    count = 0.0
    for e in range(9):
        j = table[k, e]
        v = 0.0
        ok = False
        if j >= 0:
            uj = np.uint64(j)
            var = noise[uj] * noise[uj]
            var = 0.0 if np.isnan(var) else var
            if active[uj] and var != np.inf:
                ok = True
                v = var
        total += v
        count += 1.0 if ok else 0.0
    own = noise[k] * noise[k]
    if own == np.inf:
        return np.inf
    return np.sqrt(total / max(count, 1.0))


@numba.njit(inline="always", error_model="numpy")
def _start_buffers(k, c, q, ctl, prox, distant, control, inputs, mode, switch, shift, value):
    """Channel c of pixel k (flat pixel q) of :func:`reuse_start_history`: reads the
    history's control and proxy ``ctl[q]``, ``prox[q]`` and stores this frame's there (the
    guided modes; the proxy in the multiplicative mode only); its δ. ``inputs``: (alpha,
    proxy, eps) as reuse_start_history takes them."""
    alpha, proxy, eps = inputs
    guided = mode != PLAIN
    mult = mode == MULTIPLICATIVE
    sh, val, delta = _start_channel(
        distant[k, c], control[k, c], alpha[k], proxy[k, c] if mult else 0.0,
        np.float64(ctl[q]) if guided else 0.0, np.float64(prox[q]) if mult else 0.0,
        eps[c], mode, switch,
    )  # fmt: skip
    shift[k, c] = sh
    value[k, c] = val
    if guided:
        ctl[q] = _stored(control[k, c])
    if mult:
        prox[q] = _stored(_pos(proxy[k, c]))
    return delta


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def reuse_start_history(
    distant, control, alpha, proxy, active, index, acc_n, ctl, prox, eps, mode, switch,
    tolerance, noise, table, shift, value, n_out, sigma,
):  # fmt: skip
    """:func:`reuse_start` on the history's float32 buffers, and the pooled noise: reads
    the frame count, control and proxy at ``index``, and stores this frame's control and
    proxy (≥ 0) there as History.write does (core.mc.history; each pixel reads and
    writes its own entries only).

    Parameters
    ----------
    distant, control, alpha, proxy, active, eps, mode, switch, tolerance : as
        :func:`reuse_start`
    index : (P,) int64, the pixels' flat index into the buffers
    acc_n : (H·W,) float32, the frame count (read); ctl, prox : 3-tuples of (H·W,)
        float32 buffers, the control and proxy per channel (read and written in the
        guided modes, the proxy in the multiplicative mode)
    noise : (P,) float64 (with ``table``, P rows) or (0,): the estimate's noise, pooled
        into ``sigma`` as core.mc.temporal._pooled_sigma does
    table : (P, 9) int32, :func:`neighbour_table`
    shift, value : (P, 3) float64, n_out : (P,) float64, sigma : (P,) or (0,) float64,
        written
    """
    use_noise = sigma.shape[0] > 0
    ctl_r, ctl_g, ctl_b = ctl
    prox_r, prox_g, prox_b = prox
    for k in numba.prange(distant.shape[0]):
        q = np.uint64(index[k])
        a = (alpha, proxy, eps)
        d0 = _start_buffers(k, 0, q, ctl_r, prox_r, distant, control, a, mode, switch, shift, value)
        d1 = _start_buffers(k, 1, q, ctl_g, prox_g, distant, control, a, mode, switch, shift, value)
        d2 = _start_buffers(k, 2, q, ctl_b, prox_b, distant, control, a, mode, switch, shift, value)
        n_out[k] = _cut(np.float64(acc_n[q]) if active[k] else 0.0, d0, d1, d2, mode, tolerance)
        if use_noise:
            sigma[k] = _pooled_sigma(noise, active, table, k)


#: Pixels per parallel task of :func:`reuse_finish_history`, and per block of it.
_FINISH_TASK = 1024
_FB = 8
#: Rows of a block's float64 buffer (each _FB long): the 9 neighbours' values per
#: channel (row 3e + c), whether each counts (1.0 or 0.0), and the pixel's history
#: accumulation, frame count, pooled noise, shift, estimate, value, the noise test's
#: exponent.
_FOK = 27 * _FB
_FP0, _FP1, _FP2, _FN, _FSG, _FS0, _FS1, _FS2, _FD0, _FD1, _FD2, _FA0, _FA1, _FA2, _FMM = (
    (36 + r) * _FB for r in range(15)
)
_FROWS = 51


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def reuse_finish_history(
    distant, value, shift, n_in, active, index, acc, acc_n, table, clamp, sigma, floor,
    mode, noise_sigmas, min_weight, out, n_new,
):  # fmt: skip
    """:func:`reuse_finish` on the history's float32 buffers, with the neighbourhood of
    ``value`` (:func:`_neighbours`) taken per pixel: reads the accumulation at
    ``index`` and stores the new one and the frame count there.

    Parameters
    ----------
    distant, value, shift, n_in, active, clamp, floor, mode, noise_sigmas, min_weight :
        as :func:`reuse_finish`
    index : (P,) int64; acc : 3-tuple of (H·W,) float32 buffers, the accumulation per
        channel (read and written); acc_n : (H·W,) float32, the frame count (written)
    table : (P, 9) int32, :func:`neighbour_table`; sigma : (P,) float64, the pooled
        noise, or (0,): no noise test
    out : (P, 3) float64, n_new : (P,) float64, written
    """
    finite_clamp = np.isfinite(clamp)
    use_noise = sigma.shape[0] > 0
    acc_r, acc_g, acc_b = acc
    n_pix = distant.shape[0]
    n_tasks = (n_pix + _FINISH_TASK - 1) // _FINISH_TASK
    for t in numba.prange(n_tasks):
        # Pixels in blocks of _FB, through stages: (1) the reads (scalar), (2) the
        # neighbourhood statistics, the clamp and the noise test's exponent, straight-line
        # float64 code the compiler vectorises (_neighbours' and reuse_finish's operations
        # in their order per pixel: the divisions and square roots then run 8 at a
        # time), (3) the library exp, (4) the accumulation and the stores. Lanes past a
        # partial block's end hold stale values that are never stored.
        fb = np.zeros(_FROWS * _FB)
        end = min(n_pix, (t + 1) * _FINISH_TASK)
        for k0 in range(t * _FINISH_TASK, end, _FB):
            nb = min(_FB, end - k0)
            for j in range(nb):
                k = k0 + j
                if finite_clamp:
                    for e in range(9):
                        ok, v0, v1, v2 = _neighbour(value, active, table, k, e)
                        fb[(3 * e) * _FB + j] = v0
                        fb[(3 * e + 1) * _FB + j] = v1
                        fb[(3 * e + 2) * _FB + j] = v2
                        fb[_FOK + e * _FB + j] = 1.0 if ok else 0.0
                q = np.uint64(index[k])
                fb[_FP0 + j] = np.float64(acc_r[q])
                fb[_FP1 + j] = np.float64(acc_g[q])
                fb[_FP2 + j] = np.float64(acc_b[q])
                fb[_FN + j] = n_in[k]
                fb[_FSG + j] = sigma[k] if use_noise else 0.0
                fb[_FS0 + j] = shift[k, 0]
                fb[_FS1 + j] = shift[k, 1]
                fb[_FS2 + j] = shift[k, 2]
                fb[_FD0 + j] = distant[k, 0]
                fb[_FD1 + j] = distant[k, 1]
                fb[_FD2 + j] = distant[k, 2]
                fb[_FA0 + j] = value[k, 0]
                fb[_FA1 + j] = value[k, 1]
                fb[_FA2 + j] = value[k, 2]
            for j in range(_FB):
                p0 = fb[_FP0 + j]
                p1 = fb[_FP1 + j]
                p2 = fb[_FP2 + j]
                if finite_clamp:
                    t0 = t1 = t2 = 0.0
                    q0 = q1 = q2 = 0.0
                    count = 0.0
                    for e in range(9):
                        v0 = fb[(3 * e) * _FB + j]
                        v1 = fb[(3 * e + 1) * _FB + j]
                        v2 = fb[(3 * e + 2) * _FB + j]
                        t0 += v0
                        t1 += v1
                        t2 += v2
                        q0 += v0 * v0
                        q1 += v1 * v1
                        q2 += v2 * v2
                        count += fb[_FOK + e * _FB + j]
                    nn = max(count, 1.0)
                    m0 = t0 / nn
                    m1 = t1 / nn
                    m2 = t2 / nn
                    s0 = np.sqrt(max(q0 / nn - m0 * m0, 0.0))
                    s1 = np.sqrt(max(q1 / nn - m1 * m1, 0.0))
                    s2 = np.sqrt(max(q2 / nn - m2 * m2, 0.0))
                    p0 = _clip(p0, m0 - clamp * s0, m0 + clamp * s0)
                    p1 = _clip(p1, m1 - clamp * s1, m1 + clamp * s1)
                    p2 = _clip(p2, m2 - clamp * s2, m2 + clamp * s2)
                    fb[_FP0 + j] = p0
                    fb[_FP1 + j] = p1
                    fb[_FP2 + j] = p2
                if use_noise:
                    fb[_FMM + j] = _noise_exponent(
                        p0, p1, p2, fb[_FS0 + j], fb[_FS1 + j], fb[_FS2 + j], fb[_FD0 + j],
                        fb[_FD1 + j], fb[_FD2 + j], fb[_FSG + j], floor, mode, noise_sigmas,
                    )  # fmt: skip
            if use_noise:
                for j in range(nb):
                    fb[_FN + j] = fb[_FN + j] * np.exp(fb[_FMM + j])
            for j in range(nb):
                k = k0 + j
                q = np.uint64(index[k])
                n = fb[_FN + j]
                lam = _weight(n, min_weight)
                on = active[k]
                a0 = (1.0 - lam) * fb[_FP0 + j] + lam * fb[_FA0 + j] if on else fb[_FA0 + j]
                a1 = (1.0 - lam) * fb[_FP1 + j] + lam * fb[_FA1 + j] if on else fb[_FA1 + j]
                a2 = (1.0 - lam) * fb[_FP2 + j] + lam * fb[_FA2 + j] if on else fb[_FA2 + j]
                acc_r[q] = _stored(a0)
                acc_g[q] = _stored(a1)
                acc_b[q] = _stored(a2)
                out[k, 0] = _output(a0, fb[_FS0 + j], fb[_FD0 + j], on, mode)
                out[k, 1] = _output(a1, fb[_FS1 + j], fb[_FD1 + j], on, mode)
                out[k, 2] = _output(a2, fb[_FS2 + j], fb[_FD2 + j], on, mode)
                nk = n + 1.0 if on else 0.0
                n_new[k] = nk
                acc_n[q] = _stored(nk)
