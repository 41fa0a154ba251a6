"""The unified direct/distant scattering estimator (P Sec. 5).

For an SSS pixel p with lighting B(p) and a per-channel profile,

    L_c(p) = (1 − γ_c)·B_c(p) + Î_c(p),

where γ_c = 1 − C_c(r0) is the energy beyond the pixel's own footprint
``r0 = sqrt(w² + h²)/2`` and Î_c estimates ``∫_{r≥r0} p_c(r)·E_θ[B_c(q)] dr``
with m samples.

Radii are drawn from the mixture of the channels' distant densities with
weights π_c ∝ γ_c, and channel c is weighted by ``γ_c·p̂_c(r)/q(r)`` (p̂_c the
distant density normalised on [r0, r_max]), which is unbiased for every
channel. The centre value serves as an exact control:

    Î_c = γ_c·B_c(p) + (1/m)·Σ_k w_c(r_k)·(B_c(q_k) − B_c(p)),

unbiased because E[w_c] = γ_c, identical to the paper's estimator when the
three channels share one profile (then w_c ≡ γ_c), and exact for constant
lighting for any m even when the channels differ. Samples that land off
screen, on another material or across a depth discontinuity fall back to the
centre ("follow surface", Jimenez et al. 2015) and so add nothing.

Work is compacted: only pixels with m > 0 are visited, their samples are laid
out contiguously, processed in bounded batches, and summed back with
``np.bincount``. Cost is proportional to Σm, never to the maximum count.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .profiles.base import Profile
from .sampling.sequence import pixel_offsets, r2_points

TWO_PI = 2.0 * np.pi


@dataclass
class Geometry:
    """Per-frame quantities of the SSS pixels that do not depend on sampling.

    All per-pixel arrays have leading length P (number of SSS pixels), in
    row-major order of the image.

    Attributes
    ----------
    shape : (H, W)
    index : (P,) int64, flat pixel index ``y·W + x``
    x, y : (P,) int64, column and row
    mat : (P,) int32, material slot
    depth : (P,) float64, scene units
    fw, fh : (P,) float64, pixel footprint, scene units per pixel
    r0 : (P,) float64, direct-scattering radius, scene units
    gamma : (P, 3) float64, distant energy ratio per channel
    weight_scale : (P, 3) float64, γ_c / (distant mass of channel c)
    lo, hi : (P, 3) float64, sampling bounds in the profile's u-space
    chromatic : (P,) bool, the slot's channels have different profiles
    """

    shape: tuple[int, int]
    index: np.ndarray
    x: np.ndarray
    y: np.ndarray
    mat: np.ndarray
    depth: np.ndarray
    fw: np.ndarray
    fh: np.ndarray
    r0: np.ndarray
    gamma: np.ndarray
    weight_scale: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    chromatic: np.ndarray

    @cached_property
    def gamma_sum(self) -> np.ndarray:
        """(P,) Σ_c γ_c."""
        return self.gamma.sum(axis=1)

    @cached_property
    def cum(self) -> np.ndarray:
        """(P, 2) cumulative channel-selection probabilities γ_c/Σγ (R, R+G)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            pi = self.gamma / self.gamma_sum[:, None]
        return np.nan_to_num(np.cumsum(pi, axis=1)[:, :2])

    @cached_property
    def top(self) -> np.ndarray:
        """(P,) channel with the largest γ (fallback when rounding picks an empty one)."""
        return np.argmax(self.gamma, axis=1)

    @property
    def size(self) -> int:
        return int(self.index.shape[0])

    @property
    def gamma_max(self) -> np.ndarray:
        """(P,) largest γ over channels (the ε_u test of P Eq. 18)."""
        return self.gamma.max(axis=1) if self.size else np.zeros(0)

    def mask(self) -> np.ndarray:
        """(H, W) bool mask of the SSS pixels."""
        m = np.zeros(self.shape[0] * self.shape[1], dtype=bool)
        m[self.index] = True
        return m.reshape(self.shape)

    def to_image(self, values: np.ndarray, fill: float = 0.0, dtype=np.float32) -> np.ndarray:
        """Scatter (P, ...) values into an (H, W, ...) image, ``fill`` elsewhere."""
        values = np.asarray(values)
        if np.dtype(dtype).kind == "f" and values.dtype.kind == "f":
            big = np.finfo(dtype).max
            values = np.clip(values, -big, big)
        out = np.full((self.shape[0] * self.shape[1], *values.shape[1:]), fill, dtype=dtype)
        out[self.index] = values
        return out.reshape(*self.shape, *values.shape[1:])


def prepare(depth: np.ndarray, material: np.ndarray, camera, profile: Profile) -> Geometry:
    """Find the SSS pixels and their footprint, r0, γ and sampling bounds.

    Parameters
    ----------
    depth : (H, W) float, planar depth in scene units, inf = background
    material : (H, W) int, slot (0 = no SSS)
    camera : core.camera.Camera
    profile : core.profiles.Profile

    Returns
    -------
    Geometry
    """
    h, w = depth.shape
    mat_flat = material.reshape(-1)
    depth_flat = depth.reshape(-1)
    scatters = np.zeros(max(profile.n_slots, 1), dtype=bool)
    scatters[: profile.n_slots] = profile.scatters()
    in_table = (mat_flat > 0) & (mat_flat < profile.n_slots)
    ok = in_table & np.isfinite(depth_flat)
    ok[ok] = scatters[mat_flat[ok]]
    index = np.flatnonzero(ok).astype(np.int64)
    mat = mat_flat[index].astype(np.int32)
    z = depth_flat[index].astype(np.float64)
    fw, fh = camera.footprint(z)
    r0 = 0.5 * np.sqrt(fw * fw + fh * fh)
    region = profile.region(r0, mat)
    y, x = np.divmod(index, w)
    return Geometry(
        shape=(h, w), index=index, x=x, y=y, mat=mat, depth=z, fw=fw, fh=fh, r0=r0,
        gamma=region.gamma, weight_scale=region.weight_scale, lo=region.lo, hi=region.hi,
        chromatic=profile.chromatic()[mat] if index.size else np.zeros(0, dtype=bool),
    )


@dataclass
class DistantEstimate:
    """Result of the Monte Carlo step.

    Attributes
    ----------
    distant : (P, 3) float64, Î per channel (linear, same units as lighting)
    samples : int, samples actually taken (Σm)
    fallback : int, samples that fell back to the centre value
    """

    distant: np.ndarray
    samples: int
    fallback: int


def _chunks(counts: np.ndarray, limit: int):
    """Split the active pixel list into contiguous runs of at most ``limit`` samples."""
    ends = np.cumsum(counts)
    start = 0
    n = counts.shape[0]
    while start < n:
        base = ends[start - 1] if start else 0
        stop = int(np.searchsorted(ends, base + limit, side="right"))
        stop = max(stop, start + 1)
        yield start, min(stop, n)
        start = stop


def estimate_distant(
    geom: Geometry,
    lighting: np.ndarray,
    depth: np.ndarray,
    material: np.ndarray,
    profile: Profile,
    counts: np.ndarray,
    *,
    frame: int,
    seed: int,
    depth_slope: float,
    chunk_samples: int = 1 << 20,
) -> DistantEstimate:
    """Estimate Î for every SSS pixel with the given per-pixel sample counts.

    Parameters
    ----------
    geom : Geometry from :func:`prepare`
    lighting : (H, W, 3) float32, B (linear)
    depth : (H, W) float, planar depth, scene units
    material : (H, W) int, slot
    profile : Profile
    counts : (P,) int, samples per SSS pixel (0 = direct only)
    frame, seed : int, select the per-pixel R2 offsets
    depth_slope : float, follow-surface tolerance (see SSSParams.depth_slope)
    chunk_samples : int, batch size bound (memory)

    Returns
    -------
    DistantEstimate
    """
    h, w = geom.shape
    light = lighting.reshape(-1, 3)
    depth_flat = depth.reshape(-1)
    mat_flat = material.reshape(-1)
    distant = geom.gamma * light[geom.index].astype(np.float64)
    counts = np.asarray(counts, dtype=np.int64)
    gsum = geom.gamma_sum
    active = np.flatnonzero((counts > 0) & (gsum > 0))
    total = int(counts[active].sum())
    fallback = 0
    if total == 0:
        return DistantEstimate(distant, 0, 0)
    sx_all, sy_all = pixel_offsets(geom.x[active], geom.y[active], frame, seed)
    act_counts = counts[active]
    light32 = np.ascontiguousarray(light, dtype=np.float32)
    for a, b in _chunks(act_counts, chunk_samples):
        pix = active[a:b]
        c = act_counts[a:b]
        n = int(c.sum())
        local = np.repeat(np.arange(b - a), c)
        starts = np.cumsum(c) - c
        k = np.arange(n) - np.repeat(starts, c) + 1
        u, v = r2_points(sx_all[a:b][local], sy_all[a:b][local], k)
        p = pix[local]

        # Pick channel c with probability γ_c/Σγ, then rescale u to reuse it.
        c0 = geom.cum[p, 0]
        c1 = geom.cum[p, 1]
        ch = (u >= c0).astype(np.int64) + (u >= c1)
        ch = np.where(geom.gamma[p, ch] > 0, ch, geom.top[p])
        lo = np.where(ch == 0, 0.0, np.where(ch == 1, c0, c1))
        width = geom.gamma[p, ch] / gsum[p]
        uu = np.clip((u - lo) / width, 0.0, np.nextafter(1.0, 0.0))

        mat = geom.mat[p]
        flat = p * 3 + ch
        r = profile.sample(uu, np.take(geom.lo, flat), np.take(geom.hi, flat), mat, ch)
        theta = TWO_PI * v
        qx = np.rint(geom.x[p] + r * np.cos(theta) / geom.fw[p]).astype(np.int64)
        qy = np.rint(geom.y[p] + r * np.sin(theta) / geom.fh[p]).astype(np.int64)
        centre_idx = geom.index[p]
        inside = (qx >= 0) & (qx < w) & (qy >= 0) & (qy < h)
        q = np.where(inside, qy * w + qx, centre_idx)
        ok = inside & (mat_flat[q] == mat)
        ok &= np.abs(depth_flat[q] - geom.depth[p]) <= depth_slope * r
        fallback += n - int(np.count_nonzero(ok))
        # A rejected sample reads the centre, so its difference is exactly 0.
        q = np.where(ok, q, centre_idx)
        diff = light32[q] - light32[centre_idx]

        if geom.chromatic[pix].any():
            dens = profile.pdf(r, mat)
            if profile.pixel_weight_scale:
                dens = dens * geom.weight_scale[p]
            norm = dens.sum(axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(norm > 0, gsum[p] / norm, 0.0).astype(np.float32)
            weight = dens * scale[:, None]
        else:  # one profile for all channels: w_c = γ_c exactly
            weight = geom.gamma[p]
        contrib = diff * weight
        for ci in range(3):
            distant[pix, ci] += np.bincount(local, weights=contrib[:, ci], minlength=b - a) / c
    return DistantEstimate(distant, total, fallback)
