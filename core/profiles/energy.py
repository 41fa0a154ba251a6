"""The energy of each material's subsurface method, per slot and per pixel.

The post-process keeps the lighting's level: its Burley profile is normalised,
so the scattered light ``L`` carries as much energy as ``B`` did. Cycles'
Christensen-Burley (BURLEY) does the same, but its random walks
(RANDOM_WALK, RANDOM_WALK_SKIN) return the share of light the volume does not
absorb, which depends on the albedo, the view angle and the surface's
curvature. The fitted model (:mod:`.random_walk`) gives that share relative to
the Diffuse Color pass the composite multiplies by, and the post scales
``L`` by it on the pixels of such materials:

    L_c → e_c · V(A_c, μ) · C(A_c, ℓ_c·H) · L_c

with per slot the energy e_c, albedo A_c and mean free path ℓ_c of
:func:`.random_walk.shape` and :func:`.random_walk.mean_free_path`, and per
pixel μ the cosine between the view ray and the normal and H the mean
curvature (:func:`.random_walk.view_factor`, :func:`.random_walk.curvature_factor`).

:class:`SlotEnergy` holds the per-slot half; core.energy finds μ and H on the
depth buffer and applies it. A profile whose slots are all BURLEY has none
(``profile.energy`` is None), and the post then changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import random_walk


@dataclass(frozen=True)
class SlotEnergy:
    """The random-walk energy of a profile's slots (BURLEY slots: none).

    Attributes
    ----------
    methods : tuple of K str, the subsurface method of each slot (BURLEY for slot 0,
        non-scattering slots and every slot the model does not apply to)
    albedo : (K, 3) float64, the Base Color per slot (linear, in [0, 1])
    ell : (K, 3) float64, the walk's mean free path per slot and channel, scene units
    energy : (K, 3) float64, dimensionless: e of :func:`.random_walk.shape` (1 for BURLEY)
    """

    methods: tuple[str, ...]
    albedo: np.ndarray
    ell: np.ndarray
    energy: np.ndarray

    @property
    def n_slots(self) -> int:
        return len(self.methods)

    def modelled(self) -> np.ndarray:
        """(K,) bool: slots whose light the model scales (a random-walk method)."""
        return np.array([m != "BURLEY" for m in self.methods], dtype=bool)

    def factors(self, mat: np.ndarray, cos_view: np.ndarray, curvature: np.ndarray) -> np.ndarray:
        """(P, 3) float64 factor on L of P pixels: ``e · V(A, μ) · C(A, ℓ·H)`` (1 on BURLEY slots).

        Parameters
        ----------
        mat : (P,) int, compact slot of each pixel
        cos_view : (P,) float, |cos| between the view ray and the normal (1: along it)
        curvature : (P,) float, mean curvature H, 1/scene unit (> 0 convex; 0: flat)
        """
        mat = np.asarray(mat)
        out = np.ones((mat.size, 3))
        mu = np.asarray(cos_view, dtype=np.float64)
        h = np.asarray(curvature, dtype=np.float64)
        for slot in np.unique(mat):
            method = self.methods[int(slot)]
            if method == "BURLEY":
                continue
            rows = mat == slot
            a = self.albedo[slot]
            out[rows] = (
                self.energy[slot]
                * random_walk.view_factor(a, mu[rows], method)
                * random_walk.curvature_factor(a, h[rows, None] * self.ell[slot], method)
            )
        return out

    def describe(self, slot: int) -> dict:
        """The slot's model for reports and the UI."""
        slot = int(slot)
        return {
            "method": self.methods[slot],
            "base_color": self.albedo[slot].tolist(),
            "mean_free_path": self.ell[slot].tolist(),
            "energy": self.energy[slot].tolist(),
        }
