"""The compiled kernels, one module per domain (numba, parallel over pixels).

Every pass takes arrays and numbers only: what it needs of the algorithm's
objects (Geometry, profile tables, parameters) is unpacked by the compiled side
of its twin, beside the NumPy side in the algorithm's module
(:mod:`core.backends.twins`). Importing this package imports numba; the rest of
the core reaches it only through :func:`core.backends.twins.kernels`, which does
so lazily.

Domains: :mod:`.sampling` (the sampling step), :mod:`.surface` (the depth-buffer
surface), :mod:`.region` (the Burley distant region), :mod:`.adaptive` (SPVG),
:mod:`.history` (the history step, reprojection, reads and writes), :mod:`.image`
(the composite and float maps), :mod:`.separable` (the separable passes),
:mod:`.temporal` (the temporal reuse); :mod:`.common` holds their shared inline
helpers, :mod:`.per_sample` those the sampling pass inlines per sample, and
:mod:`.compile` compiles them all.

Compiled code is cached on disk (numba's ``cache=True``; :mod:`core.backends.cache`
chooses where). An extension built by ``make extension`` ships them compiled
(:mod:`core.backends.shipped`): importing this package imports every domain and
points its passes at the shipped build first.
"""

import numba  # noqa: F401  (fails here, not inside a pass, where numba is missing)

from .. import shipped

shipped.attach(__name__)
