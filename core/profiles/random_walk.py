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

In units of ℓ the walk's profile depends on the albedo A, the anisotropy g
and the view angle only (the walk is scale invariant; g keeps the reduced
extinction ``1/ℓ``). The model is the Burley profile that best fits it, and
the energy the walk returns relative to Cycles' subsurface albedo (the Diffuse
Color pass, which the composite multiplies by):

    d_c = ℓ_c · f_m(A_c, g)                                   (:func:`shape`)
    L_c → e_m(A_c, g) · V_m(A_c, μ) · C_m(A_c, ℓ_c·H) · L_c

per channel c, with L the post's scattered light at a pixel, μ the cosine
between its view ray and normal (:func:`view_factor`: the walk starts along
the refracted view ray, so grazing views return more; Burley's reflectance
does not depend on the view) and H the surface's mean curvature
(:func:`curvature_factor`, :func:`mean_curvature`: walks leave a convex body
more easily than a slab). f and e are tabulated over the albedo for
g ∈ {0, 0.3, 0.6, 0.9}, V over (μ, A) and C over (ℓH, A), all interpolated
linearly and held at the tables' ends. The tables
(``core/data/random_walk_fit.json``) come from Cycles renders
(``tools/random_walk/fit.py``, which states their errors): least-squares fits
of Burley's edge response to shadow edges on a semi-infinite slab, uniformly
lit slabs seen from six angles, and uniformly lit spheres of 3–50 mean free
paths. Christensen and Burley's fit of their profile to a volumetric search
light, ``d = ℓ/s(A)`` (:func:`search_light_scale`), is within 25 % of the
measured f for A in [0.1, 0.9].

Not modelled: the oblique view's asymmetric profile (at 60 degrees the best
symmetric d differs by up to 17 % and the edge response by up to 23 % of its
level), the Principled IOR and Roughness (RANDOM_WALK's entry; ≤ 1.2 % in f,
≤ 3 % in e between 1.33 and 2.0, 0 and 1), the Subsurface IOR beyond its
part in Skin's ℓ (≤ 0.3 % in f, ≤ 0.7 % in e), and the light a thin part
loses through its far side: a free slab two mean free paths thick returns 0.67
of a deep slab's red light, and what comes back from beyond the far side is
not in the passes (docs/explanation/accuracy.md §2.3).

All lengths in scene units; albedos linear in [0, 1].
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np

from ..frame import SUBSURFACE_METHODS
from .burley import blender_shape

#: Principled BSDF subsurface methods (Blender identifiers).
METHODS = SUBSURFACE_METHODS

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
def _load(path: str) -> tuple[dict, dict, dict]:
    data = json.loads(Path(path).read_text())
    if data.get("format") != FIT_FORMAT:
        raise ValueError(f"{path}: not a random-walk fit (format {data.get('format')!r})")
    tables, views, curves = {}, {}, {}
    for method, entry in data["methods"].items():
        rows = []
        for t in entry["tables"]:
            a = np.asarray(t["albedo"], dtype=np.float64)
            f = np.asarray(t["d_scale"], dtype=np.float64)
            e = np.asarray(t["energy"], dtype=np.float64)
            if not (a.ndim == 1 and a.shape == f.shape == e.shape and np.all(np.diff(a) > 0)):
                raise ValueError(f"{path}: a table of {method} is malformed")
            rows.append((float(t["anisotropy"]), a, f, e))
        rows.sort(key=lambda row: row[0])
        if not rows or rows[0][0] != 0.0:
            raise ValueError(f"{path}: {method} has no table at anisotropy 0")
        tables[method] = rows
        v = entry["view"]
        mu = np.asarray(v["cos_view"], dtype=np.float64)
        a = np.asarray(v["albedo"], dtype=np.float64)
        e = np.asarray(v["energy"], dtype=np.float64)
        if not (e.shape == (mu.size, a.size) and mu[0] == 1.0 and np.all(np.diff(mu) < 0)):
            raise ValueError(f"{path}: the view table of {method} is malformed")
        # Relative to the normal view: the anisotropy tables carry the level.
        views[method] = (mu[::-1].copy(), a, (e / e[:1])[::-1].copy())
        c = entry.get("curvature")
        if c is not None:
            x = np.asarray(c["ell_curvature"], dtype=np.float64)
            a = np.asarray(c["albedo"], dtype=np.float64)
            g = np.asarray(c["factor"], dtype=np.float64)
            if not (g.shape == (x.size, a.size) and x[0] == 0.0 and np.all(np.diff(x) > 0)):
                raise ValueError(f"{path}: the curvature table of {method} is malformed")
            curves[method] = (x, a, g)
    return tables, views, curves


def fit_tables(path: str | Path = FIT_PATH) -> dict[str, list[tuple]]:
    """method -> [(anisotropy g, albedo nodes, d scale f, energy e), ...] sorted by g.

    Each table's arrays are (N,) float64 (N may differ between tables).
    """
    return _load(str(Path(path).resolve()))[0]


def curvature_tables(path: str | Path = FIT_PATH) -> dict[str, tuple]:
    """method -> (ℓ·H nodes (M,) ascending from 0, albedo nodes (N,), (M, N) factor)."""
    return _load(str(Path(path).resolve()))[2]


def view_tables(path: str | Path = FIT_PATH) -> dict[str, tuple]:
    """method -> (cos_view nodes (M,) ascending, albedo nodes (N,), (M, N) energy relative to
    the normal view's)."""
    return _load(str(Path(path).resolve()))[1]


def lookup(tables: list[tuple], albedo, anisotropy: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(f, e) per channel from one method's tables (:func:`fit_tables`).

    Linear in the albedo within each table (held at its end values outside),
    then linear in the anisotropy between the two tables around it (held at
    the last table's anisotropy beyond it).

    Parameters
    ----------
    tables : list of (g, albedo nodes (N,), f (N,), e (N,)), sorted by g, first g = 0
    albedo : (3,) float in [0, 1]
    anisotropy : float in [0, 0.9]

    Returns
    -------
    f, e : (3,) float64
    """
    albedo = np.asarray(albedo, dtype=np.float64)
    gs = np.array([t[0] for t in tables])
    g = float(np.clip(anisotropy, gs[0], gs[-1]))
    hi = int(np.searchsorted(gs, g, side="left"))
    lo = max(hi - 1, 0)
    hi = min(hi, len(gs) - 1)
    vals = []
    for i in (lo, hi):
        _, a, f, e = tables[i]
        vals.append((np.interp(albedo, a, f), np.interp(albedo, a, e)))
    t = 0.0 if hi == lo else (g - gs[lo]) / (gs[hi] - gs[lo])
    f = (1 - t) * vals[0][0] + t * vals[1][0]
    e = (1 - t) * vals[0][1] + t * vals[1][1]
    return f, e


def shape(
    radius,
    scale: float,
    albedo,
    method: str = "RANDOM_WALK",
    subsurface_ior: float = 1.4,
    anisotropy: float = 0.0,
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
    anisotropy : float, Subsurface Anisotropy (clipped to [0, 0.9] as Cycles does)
    path : the fitted tables (default: the shipped ones)

    Returns
    -------
    d : (3,) float64, Burley shape per channel, scene units
    energy : (3,) float64, dimensionless: the method's total reflectance
        divided by Cycles' subsurface albedo (the Diffuse Color pass), i.e.
        the factor on the post-process's scattered light. 1 for BURLEY.

    Notes
    -----
    Fitted at IOR 1.5 and Roughness 0.5 (RANDOM_WALK's entry) and Subsurface
    IOR 1.4 (beyond its part in Skin's ℓ, which is exact): the data file's
    ``errors.sensitivity`` shows that other values move f by about 1 % and e
    by up to 3 %. A channel with radius 0 gets d = 0 (no scattering).

    >>> d, e = shape([1.0, 1.0, 1.0], 0.1, [0.8, 0.8, 0.8], "BURLEY")
    >>> [round(float(v), 6) for v in d], e.tolist()
    ([0.007958, 0.007958, 0.007958], [1.0, 1.0, 1.0])
    """
    ell = mean_free_path(radius, scale, albedo, method, subsurface_ior)
    if method == "BURLEY":
        return ell, np.ones(3)
    if not math.isfinite(anisotropy):
        raise ValueError(f"anisotropy must be a finite number, got {anisotropy!r}")
    a = np.clip(_triple("albedo", albedo), 0.0, 1.0)
    g = min(max(float(anisotropy), ANISOTROPY_RANGE[0]), ANISOTROPY_RANGE[1])
    f, e = lookup(fit_tables(path)[method], a, g)
    return ell * f, e


def view_factor(
    albedo, cos_view, method: str = "RANDOM_WALK", path: str | Path = FIT_PATH
) -> np.ndarray:
    """How the walk's reflectance changes with the view angle, relative to the normal view.

    Cycles' walk starts along the view ray refracted into the surface: seen at
    a grazing angle it starts shallow and more light comes back out (Burley's
    reflectance does not depend on the view). Multiply the energy of
    :func:`shape` by this per pixel. Measured at anisotropy 0 (used for every
    anisotropy); bilinear in the view cosine and the albedo, held at the
    table's ends (85 degrees is its last node).

    Parameters
    ----------
    albedo : (3,) float, Base Color (clipped to [0, 1])
    cos_view : (...) float, |cos| of the angle between the view ray and the normal
    method : one of :data:`METHODS` (BURLEY: 1)

    Returns
    -------
    (..., 3) float64, dimensionless (1 at cos_view = 1)
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    mu = np.clip(np.abs(np.asarray(cos_view, dtype=np.float64)), 0.0, 1.0)
    if method == "BURLEY":
        return np.ones((*mu.shape, 3))
    a = np.clip(_triple("albedo", albedo), 0.0, 1.0)
    nodes_mu, nodes_a, rel = view_tables(path)[method]
    return _bilinear(a, mu, nodes_mu, nodes_a, rel)


def _bilinear(albedo: np.ndarray, x: np.ndarray, nodes_x, nodes_a, table) -> np.ndarray:
    """table (M, N) over (nodes_x, nodes_a) at per-channel albedo (3,) and x (...): (..., 3)."""
    cols = np.stack([[np.interp(albedo[c], nodes_a, row) for row in table] for c in range(3)])
    out = np.empty((*x.shape, 3))
    for c in range(3):
        out[..., c] = np.interp(x, nodes_x, cols[c])
    return out


#: Largest ℓ·H :func:`curvature_factor` uses by default (a sphere of 20 mean free paths).
MAX_ELL_CURVATURE = 0.05


def curvature_factor(
    albedo,
    ell_curvature,
    method: str = "RANDOM_WALK",
    max_ell_curvature: float = MAX_ELL_CURVATURE,
    path: str | Path = FIT_PATH,
) -> np.ndarray:
    """How a convex surface raises the walk's reflectance, relative to a flat one.

    On a sphere of radius R a walk that would be absorbed deep below a flat
    surface leaves through the curved one: uniformly lit spheres reflect
    1 + ~1.3·ℓ/R times the slab's reflectance (Burley's post-process, which keeps
    the lighting's level, does not). Multiply the energy of :func:`shape` by
    this per pixel and channel. Tabulated over ``x = ℓ_c·H`` (ℓ_c the channel's
    mean free path, :func:`mean_free_path`; H the mean curvature, 1/R for a
    sphere, e.g. :func:`mean_curvature`) and the albedo, averaged over the view
    angles of the sphere; bilinear; concave surfaces (x < 0) count as flat.

    x is capped at ``max_ell_curvature``: the table (measured to x = 1/3)
    holds, for small spheres, light that crossed the whole sphere from its lit
    far side, which a scene lit from one side does not send; and a
    depth-buffer curvature has outliers at facets and silhouettes. The
    default 0.05 was chosen on the two scenes of tools/random_walk/real_case.py
    (so it is tuned, not measured); ``np.inf`` uses the whole table.

    Parameters
    ----------
    albedo : (3,) float, Base Color (clipped to [0, 1])
    ell_curvature : (..., 3) or (...) float, ℓ_c·H per pixel (and channel), dimensionless
    method : one of :data:`METHODS` (BURLEY: 1)

    Returns
    -------
    (..., 3) float64, dimensionless (1 on a flat surface)
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    x = np.nan_to_num(np.asarray(ell_curvature, dtype=np.float64))
    x = np.clip(x, 0.0, max_ell_curvature)
    if method == "BURLEY":
        return np.ones(x.shape if x.shape[-1:] == (3,) else (*x.shape, 3))
    a = np.clip(_triple("albedo", albedo), 0.0, 1.0)
    curves = curvature_tables(path)
    if method not in curves:
        return np.ones(x.shape if x.shape[-1:] == (3,) else (*x.shape, 3))
    nodes_x, nodes_a, table = curves[method]
    if x.shape[-1:] == (3,) and x.ndim >= 1:
        per = [_bilinear(a, x[..., c], nodes_x, nodes_a, table)[..., c] for c in range(3)]
        return np.stack(per, axis=-1)
    return _bilinear(a, x, nodes_x, nodes_a, table)


def mean_curvature(points: np.ndarray, normals: np.ndarray, labels=None) -> np.ndarray:
    """Mean curvature H per pixel of a depth-buffer surface (1/scene unit; > 0 convex).

    ``H ≈ ½ Σ_axis Δn·ΔP / |ΔP|²`` over the image's two axes, with central
    differences where both neighbours continue the surface (their steps within a
    factor 2 of each other), else the shorter one-sided step, else nothing (0).
    Exact for a sphere seen from outside (1/R); a cylinder gives 1/(2R).

    Parameters
    ----------
    points : (H, W, 3) float, camera-space positions (scene units; non-finite: no surface)
    normals : (H, W, 3) float, unit normals turned towards the camera
    labels : (H, W) int or None, e.g. the object or material index: a neighbour
        with another label does not continue the surface

    Returns
    -------
    (H, W) float64, 0 where it cannot be estimated
    """
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if p.ndim != 3 or p.shape[-1] != 3 or n.shape != p.shape:
        raise ValueError(f"points and normals must be (H, W, 3), got {p.shape} and {n.shape}")
    total = np.zeros(p.shape[:2])
    count = np.zeros(p.shape[:2])
    lab = None if labels is None else np.asarray(labels)
    for axis in (0, 1):
        steps = []
        for shift in (1, -1):
            with np.errstate(invalid="ignore"):  # inf − inf off the surface
                dp = np.roll(p, -shift, axis=axis) - p
                dn = np.roll(n, -shift, axis=axis) - n
            ok = np.all(np.isfinite(dp), axis=-1) & np.all(np.isfinite(dn), axis=-1)
            edge = [slice(None)] * 2
            edge[axis] = -1 if shift == 1 else 0
            ok[tuple(edge)] = False  # np.roll wraps around the border
            if lab is not None:
                ok &= np.roll(lab, -shift, axis=axis) == lab
            with np.errstate(invalid="ignore", divide="ignore"):
                length2 = np.sum(dp * dp, axis=-1)
                kappa = np.sum(dn * dp, axis=-1) / length2
            ok &= length2 > 0
            steps.append((ok, np.where(ok, length2, np.inf), np.where(ok, kappa, 0.0)))
        (ok_f, l_f, k_f), (ok_b, l_b, k_b) = steps
        both = ok_f & ok_b & (l_f <= 4.0 * l_b) & (l_b <= 4.0 * l_f)  # |ΔP| within 2x
        one = np.where(l_f <= l_b, k_f, k_b)
        kappa = np.where(both, 0.5 * (k_f + k_b), np.where(ok_f | ok_b, one, 0.0))
        total += kappa
        count += ok_f | ok_b
    with np.errstate(invalid="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), 0.0)
