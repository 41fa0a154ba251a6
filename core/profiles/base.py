"""The profile interface the unified estimator samples through.

A profile describes, per material slot and colour channel, the radial
diffusion density of the distant-scattering region ``r ≥ r0`` (P Sec. 5,
Table 2): how much energy lies there (γ), its density, and how to draw radii
from it. The estimator never looks inside a profile, so Burley, the dipole and
the artist-friendly model plug in without touching it.

The interface is split into a per-pixel and a per-sample half so that work
that depends only on the pixel (γ, sampling bounds) is done once per pixel,
and the per-sample kernels are a few vector operations on per-slot tables:

- :meth:`Profile.region` turns r0 into γ, the weight scale γ/mass and the
  sampling bounds (lo, hi) of the distant region in the profile's own
  "u-space" (e.g. tail values for Burley);
- :meth:`Profile.sample` maps u ∈ [0, 1) between lo and hi to a radius for one
  channel per sample;
- :meth:`Profile.pdf` evaluates the radial density of all channels at a
  radius (zero beyond the truncation).

Channel c of a sample is weighted by ``γ_c·p̂_c(r) / Σ_c' π_c'·p̂_c'(r)`` with
p̂_c the density normalised on the pixel's distant region. When
``γ_c·p̂_c = pdf_c·const`` with one constant per slot (true for every profile
truncated and renormalised independently of r0, such as Burley and the
tabulated dipole) the per-pixel weight scale cancels and
``pixel_weight_scale`` is False, saving a multiply per sample.

Material slots are the values of the Material Index pass: slot 0 means "no
subsurface scattering". Radii are in scene units.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

#: Burley's CDF at r = d, 1 − (e^−1 + 3·e^−1/3)/4: the share of its light within d.
CONTACT_SHARE = 1.0 - (np.exp(-1.0) + 3.0 * np.exp(-1.0 / 3.0)) / 4.0


@dataclass
class Region:
    """Distant region of P pixels.

    Attributes
    ----------
    gamma : (P, 3) float64, distant energy ratio γ_c in [0, 1]
    weight_scale : (P, 3) float64, γ_c / ∫_{r0}^{r_max} pdf_c (0 where empty)
    lo, hi : (P, 3) float64, sampling bounds in the profile's u-space
    """

    gamma: np.ndarray
    weight_scale: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


class Profile(ABC):
    """Per-slot, per-channel radial profile (see module docstring)."""

    #: Name used by the CLI and UI.
    name: str = "profile"

    @property
    @abstractmethod
    def n_slots(self) -> int:
        """Number of material slots (max Material Index + 1)."""

    @abstractmethod
    def scatters(self) -> np.ndarray:
        """(K,) bool: slots with any scattering."""

    @abstractmethod
    def chromatic(self) -> np.ndarray:
        """(K,) bool: slots whose channels have different profiles."""

    @abstractmethod
    def region(self, r0: np.ndarray, mat: np.ndarray, backend: str = "numpy") -> Region:
        """γ, weight scale and sampling bounds for pixels with radius ``r0`` (P,).

        ``backend``: one of core.params.BACKENDS (a profile with a compiled region,
        Burley's, runs it where this resolves to numba; the others ignore it).
        """

    @abstractmethod
    def sample(
        self, u: np.ndarray, lo: np.ndarray, hi: np.ndarray, mat: np.ndarray, channel: np.ndarray
    ) -> np.ndarray:
        """Radii (N,) for u (N,) in [0, 1) between bounds lo, hi (N,) of ``channel``."""

    @abstractmethod
    def pdf(self, r: np.ndarray, mat: np.ndarray) -> np.ndarray:
        """(N, 3) float32 radial density at r (N,) for all channels; 0 beyond truncation."""

    #: Whether the estimator must multiply pdf by the per-pixel weight scale.
    pixel_weight_scale: bool = True

    #: The random-walk energy of the slots (core.profiles.energy.SlotEnergy), set by
    #: core.profiles.factory where a material's subsurface method is a random walk;
    #: None: every slot keeps the lighting's level (core.energy changes nothing).
    energy = None

    def pdf_channels(self, r: np.ndarray, mat: np.ndarray) -> np.ndarray:
        """(3, N) float32 channel-major :meth:`pdf` (what the estimator uses).

        Channel-major rows broadcast against (N,) per-sample arrays without
        the cost of (N, 1) broadcasting; profiles may override for speed.
        """
        return np.ascontiguousarray(np.asarray(self.pdf(r, mat), dtype=np.float32).T)

    def describe(self, slot: int) -> dict:
        """Human-readable parameters of a slot (for reports and the UI)."""
        return {"profile": self.name, "slot": int(slot)}

    def contact_scale(self) -> np.ndarray:
        """(K,) float32, scene units: each slot's scattering length for the contact rule
        (SSSParams.contact): the largest over the channels of the radius within which
        :data:`CONTACT_SHARE` of the profile's light scatters, which is Burley's d.

        Read off the radial density on a log grid of radii (1e-7 to 1e4 scene units,
        trapezoids); 0 for a slot that does not scatter.
        """
        radii = np.geomspace(1e-7, 1e4, 4097)
        out = np.zeros(self.n_slots, np.float32)
        for slot in np.flatnonzero(self.scatters()):
            density = self.pdf_channels(radii, np.full(radii.size, slot)).astype(np.float64)
            steps = 0.5 * (density[:, 1:] + density[:, :-1]) * np.diff(radii)
            cdf = np.cumsum(steps, axis=1)
            cdf /= np.maximum(cdf[:, -1:], 1e-300)
            at = [np.searchsorted(c, CONTACT_SHARE) for c in cdf]
            out[slot] = max(radii[min(i + 1, radii.size - 1)] for i in at)
        return out
