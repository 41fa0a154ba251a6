"""The random-walk energy on a frame's pixels: L scaled before the composite.

A material whose Principled subsurface method is a random walk gets, besides
its fitted Burley shape, an energy factor on the post's scattered light ``L``
(core.profiles.energy, docs/explanation/design.md §4.5):

    L_c → e_c · V(A_c, μ) · C(A_c, ℓ_c·H) · L_c

This module finds, per subsurface pixel of such a material, what the factor
needs of the depth buffer and applies it, once per method and frame, after
the method's estimate and before the one composite (core.result):

- μ, the |cosine| between the pixel's view ray and its normal: the geometric
  normal of the depth buffer (core.geometry.surface, the one the sample
  kernels use);
- H, the mean curvature of the depth buffer
  (:func:`core.profiles.random_walk.mean_curvature`), continuing only across
  neighbours of the same object (the Object Index pass, else the material).

With ``SSSParams.distance = "planar"`` the post treats the surface as the
image plane and computes no normals: μ = 1 and H = 0 there, so only e_c
applies. Every method (Monte Carlo, separable, reference) and every tile gets
the same factor at a pixel: it reads the depth within two pixels of it (the
curvature's neighbours' normals), which a tile's halo holds (core.tiling). A
frame whose profile has no random-walk slot is returned unchanged, bit for bit.
"""

from __future__ import annotations

import numpy as np

from .frame import Frame
from .geometry import Geometry, positions, surface
from .profiles.base import Profile
from .profiles.random_walk import mean_curvature

#: How far (pixels) the factor at a pixel reads the depth buffer: the curvature takes
#: its neighbours' normals, each from their own neighbours.
REACH = 2


def view_and_curvature(
    frame: Frame, geom: Geometry, rows: np.ndarray, backend: str = "numpy"
) -> tuple[np.ndarray, np.ndarray]:
    """μ and H at the pixels ``rows`` of ``geom`` (see the module doc).

    Parameters
    ----------
    frame : Frame (depth, camera, Material Index, Object Index)
    geom : its Geometry; its ``surface`` is used where it has one, else computed
    rows : (n,) int, rows of ``geom``'s pixel arrays
    backend : one of core.params.BACKENDS, for :func:`core.geometry.surface`

    Returns
    -------
    cos_view : (n,) float64 in [0, 1], dimensionless
    curvature : (n,) float64, 1/scene unit (> 0 convex; 0 where unknown)
    """
    surf = geom.surface if geom.surface is not None else surface(frame, backend)
    h, w = frame.shape
    index = geom.index[rows]
    normal = surf.normal.reshape(h, w, 3)
    n_rows = surf.normal[index].astype(np.float64)
    cam = frame.camera
    ray = np.zeros((index.size, 3))
    ray[:, 2] = 1.0
    if cam.type != "ORTHO":
        wu, hu = cam.unit_footprint()
        cx, cy = cam.principal_point
        ray[:, 0] = (geom.x[rows] - cx) * wu
        ray[:, 1] = (geom.y[rows] - cy) * hu
        ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    cos_view = np.clip(np.abs(np.sum(n_rows * ray, axis=-1)), 0.0, 1.0)
    # The curvature on the box around the pixels, grown by what it reads.
    ly, lx = np.divmod(index, w)
    y0, y1 = max(int(ly.min()) - REACH, 0), min(int(ly.max()) + REACH + 1, h)
    x0, x1 = max(int(lx.min()) - REACH, 0), min(int(lx.max()) + REACH + 1, w)
    oy, ox = frame.origin
    points = positions(cam, frame.depth[y0:y1, x0:x1], (oy + y0, ox + x0))
    labels = frame.material if frame.objects is None else frame.objects
    box = mean_curvature(points, normal[y0:y1, x0:x1], labels[y0:y1, x0:x1])
    return cos_view, box[ly - y0, lx - x0]


def energy_factors(
    frame: Frame,
    geom: Geometry,
    profile: Profile,
    distance: str = "cycles",
    backend: str = "numpy",
) -> tuple[np.ndarray, np.ndarray] | None:
    """The rows of ``geom`` whose light the model scales, and their factors.

    Parameters
    ----------
    frame, geom : the frame and its Geometry (P subsurface pixels)
    profile : the frame's profile (its ``energy``, core.profiles.energy.SlotEnergy)
    distance : ``SSSParams.distance``; "planar" computes no normals (μ = 1, H = 0)
    backend : one of core.params.BACKENDS

    Returns
    -------
    None where no pixel of ``geom`` has a random-walk material, else
    rows : (n,) int64, rows of ``geom``'s arrays
    factors : (n, 3) float64, dimensionless

    Made once per Geometry (:meth:`Geometry.memo`): a still scene's frames share it.
    """
    table = getattr(profile, "energy", None)
    if table is None or not geom.size:
        return None

    def make():
        modelled = np.zeros(max(profile.n_slots, table.n_slots), dtype=bool)
        modelled[: table.n_slots] = table.modelled()
        rows = np.flatnonzero(modelled[geom.mat])
        if not rows.size:
            return (None,)
        if distance == "planar":
            cos_view, curvature = np.ones(rows.size), np.zeros(rows.size)
        else:
            cos_view, curvature = view_and_curvature(frame, geom, rows, backend)
        return rows, table.factors(geom.mat[rows], cos_view, curvature)

    made = geom.memo(f"energy_factors/{distance}", make)
    return None if made[0] is None else made


def scale_shaded(
    frame: Frame,
    geom: Geometry,
    profile: Profile,
    shaded: np.ndarray,
    distance: str = "cycles",
    backend: str = "numpy",
) -> np.ndarray:
    """``shaded`` (L, (P, 3), linear) with the random-walk energy applied (module doc).

    Returns ``shaded`` itself when no pixel has a random-walk material, else a
    scaled copy (same dtype).
    """
    found = energy_factors(frame, geom, profile, distance, backend)
    if found is None:
        return shaded
    rows, factors = found
    out = np.array(shaded, copy=True)
    out[rows] = out[rows] * factors
    return out
