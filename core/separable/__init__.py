"""Separable subsurface scattering (Jimenez et al. 2015), the real-time baseline.

:mod:`.kernels` builds each material's separable kernel from its profile,
:mod:`.apply` runs the horizontal and vertical passes, :mod:`.processor` is
the ``separable`` method of the registry.
"""
