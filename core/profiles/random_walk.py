"""Cycles' random-walk subsurface as a Burley shape per channel, fitted to path-traced slabs.

Cycles (4.x, 5.0) has three Principled subsurface methods. They share the
Subsurface Radius ``ρ_c`` and Scale ``s`` but not the profile:

``BURLEY``
    Christensen-Burley with shape ``d_c = ρ_c·s/(4π)``
    (:func:`~cvsss.core.profiles.burley.blender_shape`), independent of albedo.
``RANDOM_WALK``
    A volumetric random walk (Chiang et al. 2016) with extinction
    ``σt = 1/(ℓ_c·(1 − g))`` and the mean free path ``ℓ_c = ρ_c·s/(4π)`` — the
    same number as Burley's d — and a single-scattering albedo chosen so that the
    walk's multiple-scattering albedo is the Base Color. Paths enter by
    refraction through a GGX interface (the Principled IOR, alpha = Roughness²)
    and leave through a Lambertian exit.
``RANDOM_WALK_SKIN``
    The same walk with ``ℓ_c = ρ_c·s·√(3(1 − α′_c))``, α′ the reduced albedo
    whose classical dipole (Jensen et al. 2001) total reflectance, with the
    Subsurface IOR, equals the Base Color (:func:`dipole_alpha_prime`); half the
    paths enter through a Lambertian entry, half by refraction with alpha = 1.

The walk's profile is not Burley's, but in units of ℓ it depends on the
albedo A only (the walk is scale invariant; the anisotropy g keeps the reduced
extinction ``1/ℓ``). The model here is the Burley profile that best fits it:

    d_c = ℓ_c · f_m(A_c),   total reflectance = e_m(A_c) · (Cycles' albedo pass),

with ``f_m`` and ``e_m`` tabulated per method m over the albedo and
interpolated linearly (held at the end values outside the table). The tables
(``core/data/random_walk_fit.json``) are least-squares fits of a Burley edge
response to the shadow edges of Cycles renders of a semi-infinite slab
(``tools/random_walk/fit.py``, which also states the fit's error). Christensen
and Burley's own fit of their profile to a volumetric search light,
``d = ℓ/s(A)``, is :func:`search_light_scale`; the measured ``f`` is close to
``1/s`` (see the data's ``errors``).

All lengths in scene units; albedos linear in [0, 1].
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np

from .burley import blender_shape

#: Principled BSDF subsurface methods (Blender identifiers).
METHODS = ("BURLEY", "RANDOM_WALK", "RANDOM_WALK_SKIN")

#: The fitted tables (written by tools/random_walk/fit.py).
FIT_PATH = Path(__file__).resolve().parent.parent / "data" / "random_walk_fit.json"

#: Value of the data file's ``format`` field.
FIT_FORMAT = "cvsss-random-walk-fit/1"

#: Cycles clamps the subsurface IOR and anisotropy to these ranges.
IOR_RANGE = (1.01, 3.8)
ANISOTROPY_RANGE = (0.0, 0.9)


def search_light_scale(albedo: np.ndarray) -> np.ndarray:
    """Christensen & Burley's search-light fit ``s(A) = 1.85 − A + 7|A − 0.8|³``.

    Their Burley shape for a volume of mean free path ℓ lit by a narrow beam is
    ``d = ℓ/s(A)``. Dimensionless; ``albedo`` any shape.

    >>> [round(float(v), 4) for v in search_light_scale([0.2, 0.8])]
    [3.162, 1.05]
    """
    a = np.asarray(albedo, dtype=np.float64)
    return 1.85 - a + 7.0 * np.abs(a - 0.8) ** 3


def fresnel_diffuse_reflectance(eta: float) -> float:
    """Jensen et al.'s fit of the diffuse Fresnel reflectance ``F_dr(η)`` (η > 1 inside)."""
    return -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta


def dipole_reflectance(alpha_prime: np.ndarray, eta: float) -> np.ndarray:
    """Total diffuse reflectance of the classical dipole for reduced albedo α′.

    ``R = α′/2 · (1 + e^{−(4/3)A·√(3(1−α′))}) · e^{−√(3(1−α′))}``,
    ``A = (1 + F_dr)/(1 − F_dr)``: the relation Cycles inverts for Random Walk (Skin).
    """
    a = np.asarray(alpha_prime, dtype=np.float64)
    fdr = fresnel_diffuse_reflectance(eta)
    four_thirds_a = 4.0 / 3.0 * (1.0 + fdr) / (1.0 - fdr)
    root = np.sqrt(3.0 * (1.0 - a))
    return 0.5 * a * (1.0 + np.exp(-four_thirds_a * root)) * np.exp(-root)


def dipole_alpha_prime(albedo: np.ndarray, eta: float) -> np.ndarray:
    """Reduced albedo α′ whose :func:`dipole_reflectance` is ``albedo``, as Cycles finds it.

    Cycles bisects [0, 1] twelve times and takes the last midpoint (so its α′
    is within 2.5e-4 of the root); below an albedo of 1e-4 it uses 0, from
    0.995 on 0.999999. This does the same, so the Skin mean free path matches
    Cycles' to float precision.

    Parameters
    ----------
    albedo : array, Base Color per channel, clipped to [0, 1]
    eta : float, Subsurface IOR (clipped to :data:`IOR_RANGE`)

    >>> round(float(dipole_alpha_prime(0.5, 1.4)), 4)
    0.9778
    """
    a = np.clip(np.asarray(albedo, dtype=np.float64), 0.0, 1.0)
    eta = float(np.clip(eta, *IOR_RANGE))
    lo, hi = np.zeros_like(a), np.ones_like(a)
    mid = lo
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        below = dipole_reflectance(mid, eta) < a
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    out = np.where(a < 1e-4, 0.0, mid)
    return np.where(a >= 0.995, 0.999999, out)


def _triple(name: str, value) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers (R, G, B), got {value!r}")
    return a


def mean_free_path(
    radius, scale: float, albedo, method: str = "RANDOM_WALK", subsurface_ior: float = 1.4
) -> np.ndarray:
    """The walk's mean free path ℓ per channel (scene units), as Cycles sets it up.

    Parameters
    ----------
    radius : (3,) float, Subsurface Radius (>= 0)
    scale : float, Subsurface Scale (>= 0)
    albedo : (3,) float, Base Color (linear; clipped to [0, 1])
    method : one of :data:`METHODS`; BURLEY returns Burley's d
    subsurface_ior : float, Subsurface IOR (RANDOM_WALK_SKIN only)

    Returns
    -------
    (3,) float64, scene units

    >>> [round(float(v), 6) for v in mean_free_path([1, 1, 1], 0.1, [0.5] * 3)]
    [0.007958, 0.007958, 0.007958]
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    radius = _triple("radius", radius)
    d = blender_shape(radius, float(scale))  # validates radius and scale
    if method != "RANDOM_WALK_SKIN":
        return d
    a = np.clip(_triple("albedo", albedo), 0.0, 1.0)
    return radius * float(scale) * np.sqrt(3.0 * (1.0 - dipole_alpha_prime(a, subsurface_ior)))


@functools.lru_cache(maxsize=4)
def _load(path: str) -> dict:
    data = json.loads(Path(path).read_text())
    if data.get("format") != FIT_FORMAT:
        raise ValueError(f"{path}: not a random-walk fit (format {data.get('format')!r})")
    tables = {}
    for method, t in data["methods"].items():
        a = np.asarray(t["albedo"], dtype=np.float64)
        f = np.asarray(t["d_scale"], dtype=np.float64)
        e = np.asarray(t["energy"], dtype=np.float64)
        if not (a.ndim == 1 and a.shape == f.shape == e.shape and np.all(np.diff(a) > 0)):
            raise ValueError(f"{path}: table of {method} is malformed")
        tables[method] = (a, f, e)
    return tables


def fit_tables(path: str | Path = FIT_PATH) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """method -> (albedo nodes, d scale f, energy e), each (N,) float64, from the data file."""
    return _load(str(Path(path).resolve()))


def shape(
    radius,
    scale: float,
    albedo,
    method: str = "RANDOM_WALK",
    subsurface_ior: float = 1.4,
    path: str | Path = FIT_PATH,
) -> tuple[np.ndarray, np.ndarray]:
    """Burley shape d and energy factor per channel modelling ``method``'s profile.

    Parameters
    ----------
    radius : (3,) float, Subsurface Radius (>= 0)
    scale : float, Subsurface Scale (>= 0)
    albedo : (3,) float, Base Color, linear (clipped to [0, 1]); the walk's
        profile depends on it
    method : one of :data:`METHODS`
    subsurface_ior : float, Subsurface IOR (RANDOM_WALK_SKIN only)
    path : the fitted tables (default: the shipped ones)

    Returns
    -------
    d : (3,) float64, Burley shape per channel, scene units
    energy : (3,) float64, dimensionless: the method's total reflectance
        divided by Cycles' subsurface albedo (the Diffuse Color pass), i.e.
        the factor on the post-process's scattered light. 1 for BURLEY.

    Notes
    -----
    The fit holds for Subsurface Anisotropy 0, IOR 1.5 and Roughness 0.5
    (RANDOM_WALK's entry); the data file states how far other values move the
    measured profile. A channel with radius 0 gets d = 0 (no scattering).

    >>> d, e = shape([1.0, 1.0, 1.0], 0.1, [0.8, 0.8, 0.8], "BURLEY")
    >>> [round(float(v), 6) for v in d], e.tolist()
    ([0.007958, 0.007958, 0.007958], [1.0, 1.0, 1.0])
    """
    ell = mean_free_path(radius, scale, albedo, method, subsurface_ior)
    if method == "BURLEY":
        return ell, np.ones(3)
    a = np.clip(_triple("albedo", albedo), 0.0, 1.0)
    nodes, f, e = fit_tables(path)[method]
    return ell * np.interp(a, nodes, f), np.interp(a, nodes, e)
