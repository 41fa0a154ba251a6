"""The ``separable`` method's processor: kernels built once per material table."""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np

from ..energy import scale_shaded
from ..frame import Frame
from ..geometry import GeometryCache
from ..method import Method, MethodOptions
from ..params import SSSParams
from ..profiles.base import Profile
from ..profiles.factory import ProfileCache
from ..result import FrameResult, assemble
from .apply import apply
from .kernels import SlotKernel, build_kernels


class SeparableProcessor:
    """Frame-by-frame separable SSS (stateless between frames).

    Its sample count is what it reads per pixel, 2·J·taps (J separable terms;
    twice that with the linear tap filter), so sample counts compare like with
    like against the Monte Carlo methods.

    Parameters
    ----------
    method : Method of the registry (kind "separable")
    params : SSSParams (seed, depth slope, ε_u of the distant-share statistic)
    options : MethodOptions (kernel, taps, jitter; the profile choice)
    """

    def __init__(self, method: Method, params: SSSParams, options: MethodOptions) -> None:
        self.method = method
        self.params = params
        self.separable = options.separable
        self.profiles = ProfileCache(params, options.profile)
        self._kernels: tuple[Profile, dict[int, SlotKernel]] | None = None
        self._geometry = GeometryCache()

    def state(self) -> dict[str, np.ndarray]:
        return {}

    def restore(self, state: Mapping[str, np.ndarray]) -> None:
        pass

    def kernels(self, profile: Profile) -> dict[int, SlotKernel]:
        """Per-slot kernels of ``profile``, built once per profile."""
        if self._kernels is None or self._kernels[0] is not profile:
            self._kernels = (profile, build_kernels(profile, self.separable))
        return self._kernels[1]

    def process(self, frame: Frame) -> FrameResult:
        t_start = time.perf_counter()
        profile = self.profiles.get(frame)
        geom, shaded, stats = apply(
            frame,
            profile,
            self.separable,
            self.kernels(profile),
            seed=self.params.seed,
            depth_slope=self.params.depth_slope,
            # A still scene (only the lights change) reuses the last frame's Geometry.
            geom=self._geometry.get(frame, profile, backend=self.params.backend),
            backend=self.params.backend,
        )
        shaded = scale_shaded(
            frame, geom, profile, shaded, self.params.distance, self.params.backend
        )
        reads = np.full(geom.size, stats["reads_per_pixel"], np.int32)
        return assemble(
            frame,
            geom,
            self.method.name,
            shaded,
            reads,
            eps_u=self.params.eps_u,
            samples=int(reads[geom.core].sum()) if geom.core is not None else int(reads.sum()),
            fallback=stats["fallback"],
            draws=stats["tap_reads"],
            sampling_ms=stats["sampling_ms"],
            started=t_start,
            backend=self.params.backend,
        )
