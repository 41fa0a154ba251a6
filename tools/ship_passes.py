"""Compile the numba passes for the extension to ship, and put them into its zip.

``make extension`` runs both steps (core.backends.shipped)::

    .venv/bin/python tools/ship_passes.py build . build/shipped_passes [CPU ...]
    .venv/bin/python tools/ship_passes.py add build/shipped_passes dist/cvsss-*.zip

``build`` compiles every pass of the add-on at the given root once per CPU model
(default: every model of ``shipped.targets()`` for this machine's architecture) into
the folder; ``add`` puts those builds into the zip made for this platform.
"""

import sys

from cvsss.core.backends import shipped

if __name__ == "__main__":
    shipped.main(sys.argv[1:])
