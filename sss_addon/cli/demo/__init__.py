"""The main job: render (or generate) passes, post-process every method, report.

``cvsss demo --out out/demo`` writes, per scene, ``passes/``, one folder per
method and ``metrics.csv``, then ``summary.json``, ``report.md`` and PNG
plots at the top.

Sources of the passes
---------------------
blender (default)
    The scenes of :mod:`cvsss.demo_blend.scenes` (flash, regular, boids) are
    built in a fresh Blender file (bpy module, or inside Blender), a copy is
    saved as ``<out>/<scene>/<scene>.blend``, and their passes are rendered
    with Cycles (or EEVEE) by the add-on's sequence renderer. Pass frames
    already on disk are reused when the render settings are the same
    (``<out>/<scene>/demo.json``); changed settings or ``overwrite``
    render them again.
synthetic
    The analytic scenes of :mod:`cvsss.core.synthetic` (flash, regular),
    written as real multi-part EXR files and read back like rendered ones;
    no Blender needed.

Every method's results continue where a run with the same passes, methods
and parameters stopped (core.run, ``existing="continue"``) and are computed
again otherwise. The 1024-spp reference, as costly as all other methods
together, is computed on every k-th frame (``reference_every``; the first,
the (k+1)-th, …) and PSNR is averaged over those frames.

Modules, one job each: :mod:`.passes` (making or reusing the passes),
:mod:`.pipeline` (the run: every method, the ground-truth extras),
:mod:`.analysis` (the figures computed from the results), :mod:`.targets`
(the checks against the issues' targets), :mod:`.figures` (the plots) and
:mod:`.report` (``summary.json``, ``truth.json``, ``report.md``).
"""

from .passes import BLENDER_SCENES, CYCLES_SAMPLES, SOURCES, SYNTHETIC_SCENES, DemoError
from .pipeline import DEMO_METHODS, run_demo

__all__ = [
    "BLENDER_SCENES",
    "CYCLES_SAMPLES",
    "DEMO_METHODS",
    "SOURCES",
    "SYNTHETIC_SCENES",
    "DemoError",
    "run_demo",
]
