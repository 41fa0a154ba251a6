"""Shared helpers of the core tests (imported as ``helpers``: pytest puts tests/core on the path)."""

from __future__ import annotations

import numpy as np
from scipy import stats

from cvsss.core.geometry import geometry_of
from cvsss.core.mc.estimator import estimate_distant
from cvsss.core.params import SSSParams
from cvsss.core.profiles.factory import frame_profile


def shade(
    frame,
    counts,
    profile=None,
    *,
    seed=0,
    slope=2.0,
    surface=False,
    disk=False,
    hidden=1.0,
    contact=0.0,
    mirror=False,
    backend="numpy",
):
    """The unified estimator on ``frame`` with ``counts`` samples per SSS pixel.

    Parameters
    ----------
    frame : Frame
    counts : int or (P,) ints, samples per SSS pixel
    profile : Profile over the frame's compact slots (default: the frame's own)
    seed, slope : hash seed and follow-surface depth slope
    surface : weigh samples by the surface distance (SSSParams.distance)
    disk : with ``surface``, weigh them with Cycles' disk kernel (distance "cycles")
    hidden : SSSParams.hidden_light
    contact : SSSParams.contact (with the frame's Object Index pass)
    mirror : SSSParams.hidden_mirror
    backend : "numpy" or "numba"

    Returns
    -------
    geom : Geometry
    est : DistantEstimate
    shaded : (P, 3) float64, L = (1 − γ)·B + Î per SSS pixel
    """
    prof = frame_profile(frame, SSSParams()) if profile is None else profile
    geom = geometry_of(frame, prof, surface_distance=surface)
    m = np.broadcast_to(np.asarray(counts), (geom.size,)).astype(np.int64)
    est = estimate_distant(
        geom,
        frame.lighting,
        frame.depth,
        prof,
        m,
        frame=frame.number,
        seed=seed,
        depth_slope=slope,
        disk=disk,
        hidden_light=hidden,
        contact=contact,
        hidden_mirror=mirror,
        backend=backend,
    )
    b = frame.lighting.reshape(-1, 3)[geom.index].astype(np.float64)
    return geom, est, (1 - geom.gamma) * b + est.distant


def chi2_limit(dof: int, level: float = 0.999) -> float:
    """The ``level`` quantile of χ² with ``dof`` degrees of freedom (scipy)."""
    return float(stats.chi2.ppf(level, dof))


def shadow_edge(w: int = 64, h: int = 48) -> np.ndarray:
    """(h, w, 3) float32 linear lighting: a vertical shadow edge (0.05 left, 1 right), tinted."""
    x = np.arange(w)[None, :, None]
    edge = np.broadcast_to(np.where(x < w // 2, 0.05, 1.0), (h, w, 3)).astype(np.float32)
    return edge * np.array([1.0, 0.8, 0.6], np.float32)


def assert_radii_follow_cdf(prof, r: np.ndarray, edges: np.ndarray, channel: int) -> None:
    """χ² test (level 0.999) of sampled radii ``r`` against ``prof``'s radial CDF on ``edges``."""
    counts, _ = np.histogram(r, bins=edges)
    cdf = prof.radial_cdf(edges, 1)[channel]
    expected = r.size * np.diff(cdf) / (cdf[-1] - cdf[0])
    keep = expected > 5
    chi2 = float(np.sum((counts[keep] - expected[keep]) ** 2 / expected[keep]))
    assert chi2 < chi2_limit(int(keep.sum()) - 1), chi2
