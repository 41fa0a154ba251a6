"""Diffusion profiles (P Table 2) behind one interface, :class:`Profile`."""

from .artist import ArtistProfile
from .base import Profile, Region
from .burley import BurleyProfile, blender_shape
from .dipole import DipoleProfile
from .factory import PROFILE_NAMES, MixedProfile, ProfileCache, ProfileChoice

__all__ = [
    "PROFILE_NAMES",
    "ArtistProfile",
    "BurleyProfile",
    "DipoleProfile",
    "MixedProfile",
    "Profile",
    "ProfileCache",
    "ProfileChoice",
    "Region",
    "blender_shape",
]
