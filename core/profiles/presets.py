"""Measured scattering materials (seeds/004 section G, from Jensen et al. 2001).

Each preset holds the dipole parameters per colour channel (R, G, B): the
absorption σa and the reduced scattering σs′ in mm⁻¹ (the table lists
isotropic scattering, g = 0, so σs′ = σs) and the relative index of
refraction η. From them:

- the dipole profile (:class:`~cvsss.core.profiles.dipole.DipoleProfile`);
- a Burley shape per channel, ``d = ℓ / s(A_tot)`` with the mean free path
  ``ℓ = 1/σt′``, ``A_tot`` the dipole's total diffuse reflectance
  (:func:`~cvsss.core.profiles.dipole.total_reflectance`, single scattering
  included) and Christensen & Burley's search-light fit
  ``s(A) = 1.9 − A + 3.5(A − 0.8)²``.

Units
-----
Everything here is in millimetres. Scene units follow from
``unit = scale / mm_per_unit`` scene units per mm: ``mm_per_unit`` is 1000 for
a scene modelled in metres (Blender's default unit scale; use
``1000·scene.unit_settings.scale_length`` otherwise) and ``scale`` is an
artist multiplier, like the Principled BSDF's Subsurface Scale, that makes a
real-size material visible on an object not modelled at real size.

>>> sorted(PRESETS)[:3]
['apple', 'chicken1', 'chicken2']
>>> [round(v, 3) for v in get("skin1").burley_d_mm()]
[0.72, 0.366, 0.216]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .dipole import MM_PER_METRE, total_reflectance

#: name → (σa RGB mm⁻¹, σs′ RGB mm⁻¹, η), seeds/004 section G (G.1–G.11).
MEASURED = {
    "apple": ((0.0030, 0.0034, 0.0460), (2.2900, 2.3900, 1.9700), 1.3),
    "chicken1": ((0.0150, 0.0770, 0.1900), (0.1500, 0.2100, 0.3800), 1.3),
    "chicken2": ((0.0180, 0.0880, 0.2000), (0.1900, 0.2500, 0.3200), 1.3),
    "cream": ((0.0002, 0.0028, 0.0163), (7.3800, 5.4700, 3.1500), 1.3),
    "ketchup": ((0.0610, 0.9700, 1.4500), (0.1800, 0.0700, 0.0300), 1.3),
    "marble": ((0.0021, 0.0041, 0.0071), (2.1900, 2.6200, 3.0000), 1.5),
    "potato": ((0.0024, 0.0090, 0.1200), (0.6800, 0.7000, 0.5500), 1.3),
    "skimmilk": ((0.0014, 0.0025, 0.0142), (0.7000, 1.2200, 1.9000), 1.3),
    "skin1": ((0.0320, 0.1700, 0.4800), (0.7400, 0.8800, 1.0100), 1.3),
    "skin2": ((0.0130, 0.0700, 0.1450), (1.0900, 1.5900, 1.7900), 1.3),
    "wholemilk": ((0.0011, 0.0024, 0.0140), (2.5500, 3.2100, 3.7700), 1.3),
}


def search_light_scale(a: np.ndarray) -> np.ndarray:
    """Christensen & Burley's ``s(A) = 1.9 − A + 3.5(A − 0.8)²`` (search-light setup)."""
    a = np.asarray(a, dtype=np.float64)
    return 1.9 - a + 3.5 * (a - 0.8) ** 2


def unit_factor(mm_per_unit: float = MM_PER_METRE, scale: float = 1.0) -> float:
    """Scene units per millimetre, ``scale / mm_per_unit``; validates both arguments."""
    for name, value in (("mm_per_unit", mm_per_unit), ("scale", scale)):
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
            or value <= 0
        ):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(scale) / float(mm_per_unit)


@dataclass(frozen=True)
class MeasuredMaterial:
    """Dipole parameters of one measured material.

    Attributes
    ----------
    name : str
    sigma_a : (3,) tuple of float, absorption per channel, mm⁻¹
    sigma_s : (3,) tuple of float, reduced scattering per channel, mm⁻¹
    eta : float, relative index of refraction
    """

    name: str
    sigma_a: tuple[float, float, float]
    sigma_s: tuple[float, float, float]
    eta: float

    @property
    def sigma_t(self) -> np.ndarray:
        """(3,) reduced extinction σt′ = σa + σs′, mm⁻¹."""
        return np.add(self.sigma_a, self.sigma_s)

    @property
    def mean_free_path(self) -> np.ndarray:
        """(3,) ℓ = 1/σt′, mm."""
        return 1.0 / self.sigma_t

    @property
    def albedo(self) -> np.ndarray:
        """(3,) single-scattering albedo α′ = σs′/σt′."""
        return np.asarray(self.sigma_s) / self.sigma_t

    def total_reflectance(self, single_scattering: bool = True) -> np.ndarray:
        """(3,) total diffuse reflectance A_tot of the dipole profile."""
        return total_reflectance(self.sigma_a, self.sigma_s, self.eta, single_scattering)

    def burley_d_mm(self) -> np.ndarray:
        """(3,) Burley shape ``d = ℓ / s(A_tot)``, mm."""
        return self.mean_free_path / search_light_scale(self.total_reflectance())

    def burley_d(self, mm_per_unit: float = MM_PER_METRE, scale: float = 1.0) -> np.ndarray:
        """(3,) Burley shape in scene units (see module doc for the units)."""
        return self.burley_d_mm() * unit_factor(mm_per_unit, scale)

    def describe(self) -> dict:
        return {
            "name": self.name,
            "sigma_a": list(self.sigma_a),
            "sigma_s": list(self.sigma_s),
            "eta": self.eta,
            "mean_free_path_mm": self.mean_free_path.tolist(),
            "total_reflectance": self.total_reflectance().tolist(),
            "burley_d_mm": self.burley_d_mm().tolist(),
        }


PRESETS: dict[str, MeasuredMaterial] = {
    name: MeasuredMaterial(name, tuple(sa), tuple(ss), float(eta))
    for name, (sa, ss, eta) in MEASURED.items()
}


def names() -> tuple[str, ...]:
    """Preset names, sorted."""
    return tuple(sorted(PRESETS))


def get(name: str) -> MeasuredMaterial:
    """The measured material ``name`` (case-insensitive).

    Raises
    ------
    ValueError
        Unknown name; the message lists the valid ones.
    """
    key = str(name).strip().lower()
    try:
        return PRESETS[key]
    except KeyError:
        raise ValueError(
            f"unknown material preset {name!r}; valid presets: {', '.join(names())}"
        ) from None
