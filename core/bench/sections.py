"""All the sections together, in their order."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..backends import select as mc_backend
from .config import RESULT_KEYS, SECTIONS, BenchConfig, Log, MeasureRss, MeasureWorkers
from .cost import section_cost
from .fit import section_fit
from .frames import section_frames
from .jobs import CPU_LEDGER
from .pareto import section_pareto
from .rss import section_rss
from .scaling import section_coverage, section_resolution


# -- the sections together ------------------------------------------------------------
def run_sections(
    cfg: BenchConfig,
    *,
    passes: Path | None = None,
    measure_rss: MeasureRss | None = None,
    log: Log = None,
    start: float | None = None,
    measure_workers: MeasureWorkers | None = None,
) -> dict:
    """Run the sections of ``cfg.sections`` and derive the headline figures.

    Parameters
    ----------
    cfg : BenchConfig
    passes : pass directory for the Pareto sequence instead of the synthetic one
        (the timing sections stay synthetic: they need sizes and coverages the
        directory does not have)
    measure_rss : callable, see :func:`section_rss`; needed for the ``rss`` section
    measure_workers : callable BenchConfig -> dict, the ``workers`` section (the tiled post
        on Dask, run by the front-end: core starts no processes); None: the section
        records that it was skipped
    log : callable str -> None receiving progress lines, or None
    start : time.perf_counter() of the run's start (progress time stamps)

    Returns
    -------
    dict with ``section_s`` (seconds per section), ``cpu_share`` (this thread's
    CPU time over wall time while processing, per section), one entry per
    section (keys of :data:`RESULT_KEYS`), ``backend_default``, and
    ``ns_per_sample``, ``gather_ns_per_sample`` (``{backend: {size: ns}}`` of
    as_ccv, ``cost_method``) and ``overhead_fraction`` when ``cost`` ran.
    """
    if "rss" in cfg.sections and measure_rss is None:
        raise ValueError("the rss section needs measure_rss (one fresh process per configuration)")
    runners: dict[str, Callable[[], dict]] = {
        "cost": lambda: section_cost(cfg, log, start),
        "frames": lambda: section_frames(cfg, log, start),
        "fit": lambda: section_fit(cfg, log, start),
        "coverage": lambda: section_coverage(cfg, log, start),
        "resolution": lambda: section_resolution(cfg, log, start),
        "rss": lambda: section_rss(cfg, measure_rss, log, start),
        "pareto": lambda: section_pareto(cfg, log, start, passes),
        "workers": lambda: (
            measure_workers(cfg)
            if measure_workers is not None
            else {"skipped": "needs a Dask cluster: run by the front-end (cvsss bench)"}
        ),
    }
    result: dict[str, Any] = {"section_s": {}, "cpu_share": {}}
    for name in SECTIONS:
        if name not in cfg.sections:
            continue
        t0 = time.perf_counter()
        CPU_LEDGER.clear()
        result[RESULT_KEYS.get(name, name)] = runners[name]()
        result["section_s"][name] = time.perf_counter() - t0
        if CPU_LEDGER:
            wall = sum(w for w, _ in CPU_LEDGER)
            result["cpu_share"][name] = sum(c for _, c in CPU_LEDGER) / wall if wall else None
    result["backend_default"] = mc_backend.resolve("auto")
    if "cost" in result:
        cost = result["cost"]
        result["cost_method"] = "as_ccv"
        for key in ("ns_per_sample", "gather_ns_per_sample"):
            result[key] = {
                b: {k: v["as_ccv"][key] for k, v in sizes.items()}
                for b, sizes in cost["by_backend"].items()
            }
        big = list(cost["sizes"])[-1]
        result["overhead_fraction"] = {
            "size": big,
            **{m: v["overhead_fraction"] for m, v in cost["sizes"][big].items()},
        }
    return result
