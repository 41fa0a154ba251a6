"""Speed and the speed/accuracy trade, measured: the computation behind ``cvsss bench``.

Every figure is a ratio or a fit of quantities measured side by side in one
run on this machine, so it means something on any machine:

``ns_per_sample``
    Wall time of the Monte Carlo sampling step (``FrameResult.sampling_ms``)
    divided by the samples it took, at 640×360 and 1280×720 (median over
    frames 2…n of the flashing-light sequence; frame 1 has no history).
``gather_ns_per_sample``
    The roofline it is held against: the same number of random local
    gathers (3 float32 per sample, offsets uniform in a ±16-pixel square
    around the same SSS pixels) from the same lighting image with
    ``np.take``, best of three, timed right after each frame's passes with
    that frame's counts, median over the same frames. Each ratio
    ``ns_per_sample / gather_ns_per_sample`` thus compares two timings taken
    within a second of each other (a roofline taken minutes apart moved the
    ratio with the machine's drift). The size's roofline in ``cost`` is the
    fastest of the configurations' gathers.
``backend_default``, ``by_backend``
    The figures above are measured for every sampling backend that imports
    here (``SSSParams.backend``: NumPy, and the compiled numba passes), side
    by side in one interleaved run; ``ns_per_sample`` and
    ``gather_ns_per_sample`` are ``{backend: {size: ns}}``. The other sections
    run on ``backend_default``, what ``backend = "auto"`` picks.
``frame_time_ms``
    Whole-frame time (``total_ms``) per backend, size (1280×720, 1920×1080,
    2560×1440) and method (:data:`FRAME_METHODS`: the cost methods, ``as_ccv_t``
    and ``separable``), on the first frame of the sequence (no history
    yet: the adaptive methods take their initial count, an upper bound of a
    steady frame's time; see :func:`section_frames`); and ``steady``: seconds per
    steady 1920×1080 frame of ``as_ccv_t`` and ``as_ccv`` on the default backend,
    median and min–max of 5 frames each after 3 of warm-up, interleaved
    (:func:`.frames.steady_frames`; the target ``as_ccv_t_1080p_s``).
``samples_time_r2``
    R² of a linear fit of sampling-step time against samples taken over the
    frames of ``fixed`` N ∈ {8, 16, 32, 64}, ``as``, ``as_ocv``, ``as_ccv``.
``overhead_fraction``
    History update + CV bookkeeping (``update_ms``) over the whole frame
    (``total_ms``), per method.
``coverage_scaling`` / ``resolution_scaling``
    Time per frame against SSS coverage (10/50/100 % of the same image, plus
    an ε_u that leaves half of the SSS pixels without distant samples) and
    against resolution (time / pixel count should be flat).
``peak_rss_mb``
    Peak resident memory of one process post-processing one frame, per
    method and history precision. This module lists the configurations
    (:func:`rss_specs`) and tabulates what a ``measure`` callable returns for
    them (:func:`section_rss`); measuring needs one fresh process per
    configuration, which the command line does (``sss_addon.cli.bench``).
``pareto``
    Mean spp, mean sampling ms (3rd-order median over frames, P Sec. 7) and mean
    PSNR against the 1024-spp reference on the flashing-light sequence for
    ``fixed`` N ∈ {1…64}, the adaptive methods over σ0² ∈ {1e-2…1e-6} (and
    the extra σ0²/β_min of the quality calibration), and every separable
    kernel (whose "spp" is its reads per pixel, 2·J·taps).

The reference
-------------
A 1024-spp reference per frame is the expensive part. When every frame's
lighting is an affine function of one scalar, ``B_t = B_a + s_t·(B_b − B_a)``
with the same geometry (true of the synthetic flash sequence, where one light
changes intensity; checked numerically on the frames, not assumed), the
estimator is linear in B for a fixed set of samples, so the reference of
every frame is the same combination of two references computed with one
sample pattern (frame number 0, the reference's own seed). Otherwise the
reference is computed frame by frame.

The shipped quality calibration (``core/data/quality_calibration.json``) is
the calibration this bench produces (:func:`.pareto.section_pareto`,
``result["pareto"]["calibration"]``); ``cvsss bench --write-calibration``
replaces it.

Nothing here prints, spawns processes or draws: progress goes to an optional
``log`` callable, and the front-end (``sss_addon.cli.bench``) writes
``bench.json``, the calibration and the plots.

Modules: :mod:`.config` (what is measured, at which sizes), :mod:`.jobs` (running the
sequences), :mod:`.gather` (the roofline), one module per section (:mod:`.cost`,
:mod:`.frames`, :mod:`.fit`, :mod:`.scaling`, :mod:`.rss`, :mod:`.pareto`, with
:mod:`.reference`), :mod:`.sections` (all of them in order) and :mod:`.results`
(targets and JSON).
"""

from .config import QUICK, SECTIONS, BenchConfig, size_key
from .results import clean_json, evaluate_targets, to_json, write_json
from .rss import rss_specs
from .sections import run_sections

__all__ = [
    "QUICK",
    "SECTIONS",
    "BenchConfig",
    "clean_json",
    "evaluate_targets",
    "rss_specs",
    "run_sections",
    "size_key",
    "to_json",
    "write_json",
]
