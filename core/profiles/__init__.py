"""Diffusion profiles (P Table 2) behind one interface, :class:`Profile`."""

from .base import Profile, Region
from .burley import BurleyProfile, blender_shape

__all__ = ["BurleyProfile", "Profile", "Region", "blender_shape"]
