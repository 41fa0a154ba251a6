"""The Monte Carlo methods' processor: counts → sampling → shading → history.

:class:`MonteCarloProcessor` serves ``none``, ``fixed``, ``reference`` and the
adaptive methods of the registry (core.methods). It carries the per-pixel
history from frame to frame; only the Monte Carlo sampling step is timed as
the sampling time (``sampling_ms``), history and CV bookkeeping separately so their overhead can
be reported.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np

from ..energy import scale_shaded
from ..frame import Frame
from ..geometry import Geometry, GeometryCache, geometry_of, light_scale
from ..method import Method, MethodOptions
from ..params import SeparableParams, SSSParams
from ..profiles.base import Profile
from ..profiles.factory import ProfileCache
from ..result import FrameResult, assemble
from ..separable.apply import apply
from ..separable.kernels import build_kernels
from . import adaptive, temporal
from .estimator import estimate_distant
from .history import History
from .update import update

#: Kernel of the noise-free proxy of the multiplicative temporal mode: linear tap
#: reads follow sub-pixel motion of the lighting (with nearest reads the proxy moves in
#: steps and the accumulated ratio drifts behind a moving shadow).
PROXY_KERNEL = SeparableParams(kernel="pre_integrated", taps=17, filter="linear")


def history_fields(method: Method) -> tuple[str, ...]:
    """The history buffers ``method`` keeps (those :meth:`History.empty` makes for it)."""
    return History.fields(temporal=bool(method.temporal), cv=method.cv == "online")


def check_state(method: Method, state: Mapping[str, np.ndarray]) -> tuple[int, int] | None:
    """Check a :meth:`MonteCarloProcessor.state` of ``method`` read from a file.

    Parameters
    ----------
    method : Method of the registry
    state : mapping name -> array

    Returns
    -------
    (H, W) of the history, or None when ``state`` holds none.

    Raises
    ------
    ValueError
        An adaptive method's history lacks a buffer, or an array of it has the
        wrong shape, dtype or value (:meth:`History.check_arrays`).
    """
    if "h_meta" not in state:
        return None
    fields = history_fields(method) if method.adaptive else ()
    return History.check_arrays(state, "h_", fields)


class MonteCarloProcessor:
    """Post-process frames in order with one Monte Carlo method, carrying history.

    Parameters
    ----------
    method : Method of the registry (kind none, fixed, reference or adaptive)
    params : SSSParams
    options : MethodOptions (the profile choice)
    """

    def __init__(self, method: Method, params: SSSParams, options: MethodOptions) -> None:
        self.method = method
        self.params = params
        self.options = options
        self.profiles = ProfileCache(params, options.profile)
        self.history: History | None = None
        # Whether arrays of self.history are held outside (state() hands them out):
        # the next reprojection then makes a new history rather than align it in place.
        self._shared = False
        self._proxy_kernels: tuple[Profile, dict] | None = None
        self._geometry = GeometryCache()

    # -- state ------------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        """The history as named arrays (empty before the first adaptive frame): its
        own arrays, which the next frame then leaves alone."""
        self._shared = True
        return {} if self.history is None else self.history.to_arrays("h_")

    def restore(self, state: Mapping[str, np.ndarray]) -> None:
        """Continue from :meth:`state` (a state read from a file is checked first, with
        :func:`check_state`: ``core.run.SequenceRun`` does so for checkpoints)."""
        self.history = History.from_arrays(state, "h_") if "h_meta" in state else None
        self._shared = False  # from_arrays copies

    # -- the frame step -----------------------------------------------------------------
    def _counts(self, geom: Geometry, hist: History | None) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        gmax = geom.gamma_max
        valid = np.zeros(geom.size, dtype=bool)
        kind = self.method.kind
        if kind == "none":
            return np.zeros(geom.size, dtype=np.int32), valid
        if kind == "fixed":
            return np.where(gmax >= p.eps_u, p.fixed_spp, 0).astype(np.int32), valid
        if kind == "reference":
            return np.where(gmax > 0, p.reference_spp, 0).astype(np.int32), valid
        valid = hist.valid.reshape(-1)[geom.index]
        counts = adaptive.sample_counts(
            hist.read("var", geom.index, p.backend),
            hist.read("mbar", geom.index, p.backend),
            valid,
            gmax,
            p,
        )
        return counts, valid

    def _aligned_history(self, frame: Frame) -> History:
        """The history reprojected onto ``frame`` (empty on the first frame)."""
        p = self.params
        if self.history is None:
            self.history = History.empty(
                frame.shape,
                p.history_precision,
                p.eta_cv,
                p.target_variance,
                temporal=bool(self.method.temporal),
                cv=self.method.cv == "online",
            )
        elif self.history.shape != frame.shape:
            raise ValueError(
                f"frame {frame.number} is {frame.shape[1]}x{frame.shape[0]} but the "
                f"sequence started at {self.history.shape[1]}x{self.history.shape[0]}"
            )
        # A still camera's history is aligned in place (no copy of its buffers) unless
        # a state handed out holds its arrays.
        in_place, self._shared = not self._shared, False
        return self.history.reproject(
            frame.motion, frame.depth, frame.material, backend=p.backend, in_place=in_place
        )

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
        t_start = time.perf_counter()
        p = self.params
        profile = self.profiles.get(frame)
        # A tile samples its core pixels only (core.tiling): each pixel's result needs
        # its own history and the passes around it, never its neighbours' results.
        # Temporal reuse reads its 3×3 neighbours' estimates: a tile computes a 1-pixel ring.
        # A still scene (only the lights change) reuses the last frame's Geometry.
        geom = self._geometry.get(
            frame,
            profile,
            surface_distance=p.distance != "planar",
            core_only=True,
            margin=1 if self.method.temporal else 0,
            backend=p.backend,
        )
        hist = self._aligned_history(frame) if self.method.adaptive else None
        m, valid = self._counts(geom, hist)
        if counts is not None:
            m = np.asarray(counts).reshape(-1)[geom.index].astype(np.int32)

        t0 = time.perf_counter()
        est = estimate_distant(
            geom,
            frame.lighting,
            frame.depth,
            profile,
            m,
            frame=frame.number,
            seed=p.seed ^ self.method.seed_salt,
            depth_slope=p.depth_slope,
            chunk_samples=p.chunk_samples,
            variance=self.method.temporal == "guided",
            backend=p.backend,
            disk=p.distance == "cycles",
            hidden_light=p.hidden_light,
            contact=p.contact,
            hidden_mirror=p.hidden_mirror,
        )
        sampling_ms = (time.perf_counter() - t0) * 1e3

        b = geom.at(frame.lighting).astype(np.float64)
        # The part of B that does not scatter far, (1 − γ)·B: the proxy's and the
        # shading's (computed once).
        near = (1.0 - geom.gamma) * b
        distant = est.distant
        proxy = None
        if self.method.temporal == "guided" and p.temporal_mode == "multiplicative":
            t_proxy = time.perf_counter()
            proxy = self._proxy(frame, profile, geom, near)
            sampling_ms += (time.perf_counter() - t_proxy) * 1e3

        t1 = time.perf_counter()
        alpha = variance = None
        if hist is not None:
            noise = None if est.variance is None else np.sqrt(est.variance)
            alpha, variance = update(hist, geom, m, valid, est.distant, b, self.method.cv, p)
            if self.method.temporal:
                mode = "plain" if self.method.temporal == "plain" else p.temporal_mode
                cv_alpha = alpha if self.method.cv == "online" else np.ones(geom.size)
                distant, _ = temporal.reuse(
                    hist,
                    geom,
                    est.distant,
                    geom.gamma * b,
                    cv_alpha,
                    proxy,
                    m > 0,
                    mode=mode,
                    min_weight=p.temporal_min_weight,
                    clamp=p.temporal_clamp,
                    tolerance=p.temporal_tolerance,
                    noise=noise,
                    scale=light_scale(frame, profile, b, p.backend),
                    backend=p.backend,
                )
            hist.frame = frame.number
            self.history = hist
        update_ms = (time.perf_counter() - t1) * 1e3
        shaded = near + distant
        if self.method.kind != "none":  # none is the frame without scattering (F = Combined)
            shaded = scale_shaded(frame, geom, profile, shaded, p.distance, p.backend)
        return assemble(
            frame,
            geom,
            self.method.name,
            shaded,
            m,
            eps_u=p.eps_u,
            samples=est.samples,
            fallback=est.fallback,
            draws=est.samples,
            sampling_ms=sampling_ms,
            update_ms=update_ms,
            started=t_start,
            alpha=alpha,
            variance=variance,
            valid=valid,
            backend=p.backend,
        )

    def _proxy(
        self, frame: Frame, profile: Profile, geom: Geometry, near: np.ndarray
    ) -> np.ndarray:
        """(P, 3) the separable estimate of the distant integral: the noise-free proxy
        (the separable estimate of L less ``near``, (1 − γ)·B)."""
        if self._proxy_kernels is None or self._proxy_kernels[0] is not profile:
            self._proxy_kernels = (profile, build_kernels(profile, PROXY_KERNEL))
        # The separable passes read each other's intermediate results: on a tile
        # they run over every SSS pixel of the window, then the tile's are taken.
        full = geom if geom.core is None else geometry_of(frame, profile)
        _, shaded, _ = apply(
            frame,
            profile,
            PROXY_KERNEL,
            self._proxy_kernels[1],
            seed=self.params.seed,
            depth_slope=self.params.depth_slope,
            geom=full,
            backend=self.params.backend,
        )
        if full is not geom:
            shaded = shaded[np.searchsorted(full.index, geom.index)]
        return shaded - near
