"""What the bench measures, at which sizes, and its sections' names."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

Size = tuple[int, int]
Log = Callable[[str], None] | None
#: Measures the peak memory of each RSS configuration (see :func:`section_rss`).
MeasureRss = Callable[[list[dict]], list[dict]]
#: Measures the tiled post on 1 and 2 Dask workers (the front-end's; core runs no processes).
MeasureWorkers = Callable[["BenchConfig"], dict]

ADAPTIVE = ("as", "as_ocv", "as_ccv")
COST_METHODS = ("fixed", "as", "as_ocv", "as_ccv")
#: Whole-frame rows: the cost methods, the temporal one the README recommends for
#: sequences (its proxy and neighbourhood passes weigh on the frame, not the sampling
#: step) and the separable baseline.
FRAME_METHODS = (*COST_METHODS, "as_ccv_t", "separable")
#: Every section, in the order they run. ``rss`` runs last: its fresh processes take and
#: free gigabytes, and for minutes afterwards the machine (here a VM returning the freed
#: pages) slowed every timing section by spells of tens of milliseconds (the Pareto
#: sweep's sampling times by up to 1.6x on a quiet machine).
SECTIONS = ("cost", "frames", "fit", "coverage", "resolution", "pareto", "workers", "rss")
#: Section → its key in the result (default: the section's name).
RESULT_KEYS = {
    "frames": "frame_time_ms",
    "fit": "samples_time_r2",
    "coverage": "coverage_scaling",
    "resolution": "resolution_scaling",
    "rss": "peak_rss_mb",
}


@dataclass(frozen=True)
class BenchConfig:
    """What the bench measures and at which sizes (defaults: ``make bench``).

    Sizes are (width, height) in pixels; frame counts are frames of the
    60 fps synthetic sequence ``scene``.
    """

    scene: str = "flash"
    seed: int = 0
    #: The cold compile the ``jit`` figure times: every pass (None), or only the sampling
    #: build frames of this many pixels take (the smoke run: half the compile).
    jit_pixels: int | None = None
    #: Repetitions of each timed frame (minimum taken; the Pareto sweep too, not the
    #: calibration-only points whose PSNR and spp are deterministic).
    repeats: int = 2
    # ns_per_sample, gather roofline, overhead fraction
    cost_sizes: tuple[Size, ...] = ((640, 360), (1280, 720))
    #: Frames timed per backend and method; the first is not steady, so 6 gives the 5
    #: runs issue 46 judges the roofline ratio on.
    cost_frames: int = 6
    cost_fixed_spp: int = 16
    #: Sampling backends compared (those that import here; see core.backends.select).
    backends: tuple[str, ...] = ("numpy", "numba")
    # whole-frame time per backend and method
    frame_sizes: tuple[Size, ...] = ((1280, 720), (1920, 1080), (2560, 1440))
    frame_methods: tuple[str, ...] = FRAME_METHODS
    frame_frames: int = 1
    #: Steady frames (issue 46): these methods at this size (None: not measured), the
    #: history warmed up over ``steady_warmup`` frames, then ``steady_runs`` frames each,
    #: interleaved; seconds per frame, median and min–max (see frames.steady_frames).
    steady_size: Size | None = (1920, 1080)
    steady_methods: tuple[str, ...] = ("as_ccv", "as_ccv_t")
    steady_warmup: int = 3
    steady_runs: int = 5
    # samples → time fit
    fit_size: Size = (640, 360)
    fit_fixed_spp: tuple[int, ...] = (8, 16, 32, 64)
    fit_frames: int = 4
    # coverage and resolution scaling
    coverage_size: Size = (640, 360)
    coverages: tuple[float, ...] = (0.1, 0.5, 1.0)
    scaling_sizes: tuple[Size, ...] = ((320, 180), (640, 360), (1280, 720), (2560, 1440))
    scaling_frames: int = 4
    scaling_method: str = "as_ccv"
    # memory
    rss_sizes: tuple[Size, ...] = ((1280, 720), (2560, 1440))
    rss_methods: tuple[str, ...] = COST_METHODS
    rss_workers: int = 2
    rss_separable: bool = True
    # Pareto front and quality calibration
    pareto_size: Size = (320, 180)
    pareto_frames: int = 24
    warmup: int = 6
    fixed_spp: tuple[int, ...] = (1, 2, 4, 8, 16, 32, 64)
    sigmas: tuple[float, ...] = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6)
    calib_extra_sigmas: tuple[float, ...] = (1e-7,)
    calib_families: tuple[tuple[int, tuple[float, ...]], ...] = (
        (4, (1e-2, 1e-3, 1e-4)),
        (2, (1e-2, 1e-3)),
    )
    check_psnr_db: float = 45.0
    check_spp: float = 16.0
    check_method: str = "as_ccv"
    check_seed: int = 0x5EED
    transfer_size: Size | None = (160, 90)
    # the tiled post on Dask workers (issue 16): 2 workers against 1
    workers_size: Size = (1280, 720)
    workers_frames: int = 6
    workers_methods: tuple[str, ...] = ("as_ccv",)
    workers_tile: int = 256
    workers_counts: tuple[int, ...] = (1, 2)
    sections: tuple[str, ...] = SECTIONS

    def __post_init__(self) -> None:
        bad = [s for s in self.sections if s not in SECTIONS]
        if bad or not self.sections:
            raise ValueError(
                f"sections must be a non-empty subset of {', '.join(SECTIONS)}, "
                f"got {self.sections!r}"
            )

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


#: A seconds-long configuration for the smoke test.
QUICK = BenchConfig(
    jit_pixels=32 * 18,
    cost_sizes=((32, 18),),
    cost_frames=2,
    cost_fixed_spp=4,
    frame_sizes=((32, 18), (48, 27)),
    frame_methods=("fixed", "as_ccv", "as_ccv_t", "separable"),
    steady_size=(32, 18),
    steady_warmup=2,
    fit_size=(32, 18),
    fit_fixed_spp=(2, 8),
    fit_frames=2,
    coverage_size=(32, 18),
    coverages=(0.5, 1.0),
    scaling_sizes=((32, 18), (64, 36)),
    scaling_frames=2,
    rss_sizes=((32, 18),),
    rss_methods=("as_ocv",),
    rss_workers=1,
    rss_separable=False,
    pareto_size=(32, 18),
    pareto_frames=3,
    warmup=1,
    fixed_spp=(1, 4, 16),
    sigmas=(1e-2, 1e-4),
    calib_extra_sigmas=(),
    calib_families=((4, (1e-2, 1e-3)),),
    check_spp=8.0,
    transfer_size=None,
    workers_size=(64, 36),
    workers_frames=2,
    workers_tile=24,
)


def size_key(size: Sequence[int]) -> str:
    """``"WxH"`` of a (width, height) size."""
    return f"{size[0]}x{size[1]}"


def progress(log: Log, start: float | None, text: str) -> None:
    if log:
        log(text if start is None else f"[{time.perf_counter() - start:7.1f} s] {text}")
