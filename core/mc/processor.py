"""Frame-by-frame post-process of a sequence: counts → sampling → shading → history.

:class:`SequenceProcessor` carries the per-pixel history from frame to frame
for one method of the method table (core.methods). Only the Monte Carlo
sampling step is timed as the "pass time"; history and CV bookkeeping are
timed separately so their overhead can be reported.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..eval.color import REC709
from ..frame import Frame
from ..methods import Method, get_method
from ..params import SSSParams
from ..profiles import BurleyProfile, Profile
from . import adaptive, control_variates
from .estimator import Geometry, estimate_distant, prepare
from .history import History

#: XOR salt giving the reference its own random stream.
REFERENCE_SALT = 0x9E3779B9

#: Bound on the tracked luminances f̄, G (their squares stay finite in float64).
TRACK_LIMIT = 1e150


@dataclass
class FrameResult:
    """Output of one processed frame. Images are (H, W[, 3]), EXR row order.

    Attributes
    ----------
    number : int, frame number
    method : str
    sss : (H, W, 3) float32, L: subsurface-scattered lighting (B off SSS pixels), linear
    composite : (H, W, 3) float32, ``Combined − albedo·B + albedo·L`` on SSS pixels, linear
    counts : (H, W) int32, distant samples per pixel
    alpha : (H, W) float32, CV coefficient used (1 for CCV, 0 where none)
    gamma : (H, W, 3) float32, distant energy ratio per channel
    variance : (H, W) float32, tracked variance σ² after the update (luminance²)
    valid_history : (H, W) bool, the history used for the counts was valid
    mask : (H, W) bool, SSS pixels
    spp : float, mean count over SSS pixels
    samples : int, samples taken
    pass_ms : float, wall time of the sampling step only
    update_ms : float, wall time of history + CV bookkeeping
    total_ms : float, wall time of :meth:`SequenceProcessor.process`
    distant_share : float, share of SSS pixels with max γ ≥ ε_u
    fallback_share : float, share of samples that fell back to the centre
    repaired : int, input values replaced because non-finite or negative
    """

    number: int
    method: str
    sss: np.ndarray
    composite: np.ndarray
    counts: np.ndarray
    alpha: np.ndarray
    gamma: np.ndarray
    variance: np.ndarray
    valid_history: np.ndarray
    mask: np.ndarray
    spp: float
    samples: int
    pass_ms: float
    update_ms: float
    total_ms: float
    distant_share: float
    fallback_share: float
    repaired: int = 0


def _bounded(values: np.ndarray) -> np.ndarray:
    """``values`` clipped to ±TRACK_LIMIT, NaN -> 0."""
    out = np.clip(values, -TRACK_LIMIT, TRACK_LIMIT)
    nan = np.isnan(out)
    if nan.any():
        out[nan] = 0.0
    return out


def default_profile(frame: Frame, params: SSSParams) -> Profile:
    """Profile of the frame's materials (scene units): each MaterialSpec's ``profile``
    and ``options`` (core.profiles.factory); plain Burley when none asks otherwise."""
    if all(s.profile == "burley" and not s.options for s in frame.materials.values()):
        return BurleyProfile(
            frame.d_table(), truncate=params.truncate, inverse=params.burley_inverse
        )
    from ..profiles.factory import frame_profile

    return frame_profile(frame, params)


class SequenceProcessor:
    """Post-process frames in order with one method, carrying history.

    Parameters
    ----------
    method : str
        A name of ``core.methods.METHODS``.
    params : SSSParams
    profile_factory : callable (Frame, SSSParams) -> Profile, optional
        Builds the profile of a frame; defaults to :func:`default_profile`
        (see also core.profiles.factory.make_profile_factory). Rebuilt only
        when the material table changes.
    separable : core.separable.SeparableParams, optional
        Kernel, taps and jitter of the ``separable`` method (which
        :meth:`process` delegates to core.separable); default
        ``SeparableParams()``.
    """

    def __init__(
        self,
        method: str,
        params: SSSParams | None = None,
        profile_factory: Callable[[Frame, SSSParams], Profile] | None = None,
        separable=None,
    ) -> None:
        self.method: Method = get_method(method)
        self.params = params or SSSParams()
        self.profile_factory = profile_factory or default_profile
        self.history: History | None = None
        self._profile_key = None
        self._profile: Profile | None = None
        self._separable = None
        if self.method.counts == "separable":
            from ..separable.kernels import SeparableParams, SeparableProcessor

            self._separable = SeparableProcessor(
                self.params, separable or SeparableParams(), self._profile_for, self.method.name
            )

    # -- helpers ---------------------------------------------------------------
    def _profile_for(self, frame: Frame) -> Profile:
        key = (
            tuple(
                sorted(
                    (k, v.d, v.profile, repr(sorted(v.options.items())))
                    for k, v in frame.materials.items()
                )
            ),
            frame.material.max(initial=0),
        )
        if key != self._profile_key:
            self._profile = self.profile_factory(frame, self.params)
            self._profile_key = key
        return self._profile

    def _counts(self, geom: Geometry, hist: History | None) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        gmax = geom.gamma_max
        valid = np.zeros(geom.size, dtype=bool)
        kind = self.method.counts
        if kind == "none":
            return np.zeros(geom.size, dtype=np.int32), valid
        if kind == "fixed":
            return np.where(gmax >= p.eps_u, p.fixed_spp, 0).astype(np.int32), valid
        if kind == "reference":
            return np.where(gmax > 0, p.reference_spp, 0).astype(np.int32), valid
        valid = hist.valid.reshape(-1)[geom.index]
        counts = adaptive.sample_counts(
            hist.read("var", geom.index), hist.read("mbar", geom.index), valid, gmax, p
        )
        return counts, valid

    # -- the frame step -----------------------------------------------------------
    def process(self, frame: Frame, counts: np.ndarray | None = None) -> FrameResult:
        """Post-process one frame.

        Parameters
        ----------
        frame : Frame
        counts : (H, W) int, optional
            Force these sample counts (testing that CV acts on counts only);
            the history is still updated.

        Returns
        -------
        FrameResult
        """
        if self._separable is not None:
            return self._separable.process(frame)
        t_start = time.perf_counter()
        p = self.params
        profile = self._profile_for(frame)
        geom = prepare(frame.depth, frame.material, frame.camera, profile)
        hist = None
        if self.method.adaptive:
            if self.history is None or self.history.shape != frame.shape:
                if self.history is not None:
                    raise ValueError(
                        f"frame {frame.number} is {frame.shape[1]}x{frame.shape[0]} but the "
                        f"sequence started at {self.history.shape[1]}x{self.history.shape[0]}"
                    )
                self.history = History.empty(
                    frame.shape, p.history_precision, p.eta_cv, p.target_variance
                )
            hist = self.history.reproject(frame.motion, frame.depth, frame.material)
        m, valid = self._counts(geom, hist)
        if counts is not None:
            m = np.asarray(counts).reshape(-1)[geom.index].astype(np.int32)

        seed = p.seed ^ REFERENCE_SALT if self.method.counts == "reference" else p.seed
        t0 = time.perf_counter()
        est = estimate_distant(
            geom,
            frame.lighting,
            frame.depth,
            frame.material,
            profile,
            m,
            frame=frame.number,
            seed=seed,
            depth_slope=p.depth_slope,
            chunk_samples=p.chunk_samples,
        )
        pass_ms = (time.perf_counter() - t0) * 1e3

        b = frame.lighting.reshape(-1, 3)[geom.index].astype(np.float64)
        shaded = (1.0 - geom.gamma) * b + est.distant

        t1 = time.perf_counter()
        alpha = np.zeros(geom.size)
        variance = np.zeros(geom.size)
        if hist is not None:
            alpha, variance = self._update(hist, geom, m, valid, est.distant, b)
            self.history = hist
            self.history.frame = frame.number
        update_ms = (time.perf_counter() - t1) * 1e3

        big = float(np.finfo(np.float32).max)
        shaded = np.clip(shaded, 0.0, big)
        albedo = frame.albedo.reshape(-1, 3)[geom.index]
        composite = frame.combined.copy()
        comp_flat = composite.reshape(-1, 3)
        comp_flat[geom.index] = np.clip(comp_flat[geom.index] + albedo * (shaded - b), 0.0, big)
        sss = frame.lighting.copy()
        sss.reshape(-1, 3)[geom.index] = shaded
        n = geom.size
        return FrameResult(
            number=frame.number,
            method=self.method.name,
            sss=sss,
            composite=np.maximum(composite, 0.0),
            counts=geom.to_image(m, 0, np.int32),
            alpha=geom.to_image(alpha),
            gamma=geom.to_image(geom.gamma),
            variance=geom.to_image(variance),
            valid_history=geom.to_image(valid, False, bool),
            mask=geom.mask(),
            spp=float(m.mean()) if n else 0.0,
            samples=est.samples,
            pass_ms=pass_ms,
            update_ms=update_ms,
            total_ms=(time.perf_counter() - t_start) * 1e3,
            distant_share=float(np.mean(geom.gamma_max >= p.eps_u)) if n else 0.0,
            fallback_share=est.fallback / est.samples if est.samples else 0.0,
            repaired=frame.repaired,
        )

    def _update(self, hist, geom, m, valid, distant, b):
        """History (and CV) update after sampling; returns (α, σ²) per SSS pixel."""
        p = self.params
        idx = geom.index
        # Tracked luminances are bounded so that their squares (σ², Σ) stay
        # finite in float64 whatever the exposure and HDR input.
        with np.errstate(over="ignore", invalid="ignore"):
            f_bar = (distant * p.exposure) @ REC709
            g_known = ((geom.gamma * b) * p.exposure) @ REC709
        f_bar = _bounded(f_bar)
        g_known = _bounded(g_known)
        alpha = np.zeros(geom.size)
        cv = self.method.cv
        if cv == "online":
            jv = hist.cv_valid.reshape(-1)[idx] & valid
            sxx, sxy, syy = (np.where(jv, hist.read(k, idx), 0.0) for k in ("sxx", "sxy", "syy"))
            zf = np.where(jv, hist.read("zf", idx), f_bar)
            zg = np.where(jv, hist.read("zg", idx), g_known)
            alpha = control_variates.cv_coefficient(sxy, syy, f_bar, g_known, p.eps_alpha)
            tracked = control_variates.residual(f_bar, g_known, alpha)
            e = p.eta_cv
            df, dg = f_bar - zf, g_known - zg
            k = e * (1.0 - e)
            hist.write("sxx", idx, np.where(jv, (1 - e) * sxx + k * df * df, 0.0))
            hist.write("sxy", idx, np.where(jv, (1 - e) * sxy + k * df * dg, 0.0))
            hist.write("syy", idx, np.where(jv, (1 - e) * syy + k * dg * dg, 0.0))
            hist.write("zf", idx, np.where(jv, (1 - e) * zf + e * f_bar, f_bar))
            hist.write("zg", idx, np.where(jv, (1 - e) * zg + e * g_known, g_known))
            cvv = np.zeros(hist.shape[0] * hist.shape[1], dtype=bool)
            cvv[idx] = m > 0
            hist.cv_valid = cvv.reshape(hist.shape)
        elif cv == "constant":
            alpha = np.ones(geom.size)
            tracked = control_variates.residual(f_bar, g_known, alpha)
        else:
            tracked = f_bar
        mu, var, mbar, new_valid = adaptive.update_history(
            hist.read("mu", idx),
            hist.read("var", idx),
            hist.read("mbar", idx),
            valid,
            tracked,
            m,
            p,
        )
        hist.write("mu", idx, mu)
        hist.write("var", idx, var)
        hist.write("mbar", idx, mbar)
        vflat = np.zeros(hist.shape[0] * hist.shape[1], dtype=bool)
        vflat[idx] = new_valid
        hist.valid = vflat.reshape(hist.shape)
        alpha = np.where(m > 0, alpha, 0.0)
        return alpha, np.where(m > 0, var, 0.0)
