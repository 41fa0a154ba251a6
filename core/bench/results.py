"""The targets the bench's figures are held against, and its JSON."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ..io.atomic import write_text
from ..params import PAPER_DEFAULTS


# -- targets and JSON -------------------------------------------------------------------
def _target(value: float | None, target: float, op: str, **extra) -> dict:
    ok = value is not None and not (isinstance(value, float) and math.isnan(value))
    met = ok and (value <= target if op == "<=" else value >= target)
    return {"value": value, "target": f"{op} {target:g}", "met": bool(met), **extra}


def evaluate_targets(result: dict) -> dict:
    """The issue's targets as ``{value, target, met}``."""
    t: dict[str, dict] = {}
    cost = result.get("cost")
    if cost:
        # The compiled sampling pass within 4x of the gather roofline (issue 46). NumPy is
        # the fallback where numba has no wheel: measured beside it, no target.
        limits = {"numba": 4.0}
        for b, sizes in cost.get("by_backend", {"": cost["sizes"]}).items():
            if b == "numpy":
                continue
            # Judged on the median of the per-run ratios (issue 46), where measured.
            ratios = {
                k: v["as_ccv"].get("ratio_median", v["as_ccv"]["ratio_to_gather"])
                for k, v in sizes.items()
            }
            name = f"ns_per_sample_vs_gather_{b}" if b else "ns_per_sample_vs_gather"
            spread = {
                k: [v["as_ccv"].get("ratio_min"), v["as_ccv"].get("ratio_max")]
                for k, v in sizes.items()
            }
            runs = min(v["as_ccv"].get("ratio_runs", 0) for v in sizes.values())
            # Issue 46 holds numba to 4x at 1280x720: the largest size measured decides.
            largest = max(ratios, key=lambda k: int(k.split("x")[0]) * int(k.split("x")[1]))
            t[name] = _target(
                ratios[largest],
                limits.get(b, 4.0),
                "<=",
                per_size=ratios,
                spread=spread,
                runs=runs,
                method="as_ccv",
                size=largest,
            )
        big = list(cost["sizes"])[-1]
        t["overhead_fraction_as_ocv"] = _target(
            cost["sizes"][big]["as_ocv"]["overhead_fraction"], 0.25, "<=", size=big
        )
    fit = result.get("samples_time_r2")
    if fit:
        t["samples_time_r2"] = _target(fit["value"], 0.95, ">=", size=fit["size"])
    rss = result.get("peak_rss_mb")
    if rss:
        big = max(
            (r for r in rss["rows"] if r.get("peak_rss_mb") is not None),
            key=lambda r: (int(r["size"].split("x")[0]), r["peak_rss_mb"]),
            default=None,
        )
        if big is not None:
            t["peak_rss_mb_largest"] = _target(
                big["peak_rss_mb"],
                4096.0,
                "<=",
                size=big["size"],
                method=big["method"],
                precision=big["precision"],
            )
    par = result.get("pareto")
    if par:
        d = next(
            (e for e in par["as_ccv_vs_fixed"] if e["value"] == PAPER_DEFAULTS["target_variance"]),
            None,
        )
        if d:
            t["as_ccv_time_vs_fixed_at_equal_psnr"] = _target(
                d["ratio"],
                0.5,
                "<=",
                psnr_db=d["psnr_db"],
                extrapolated=d["extrapolated"],
                sigma0_sq=d["value"],
            )
        q = par["quality_checks"].get("psnr")
        if q:
            t["quality_45db_error_db"] = _target(
                abs(q["error"]), 2.0, "<=", measured_psnr_db=q["measured_psnr_db"]
            )
    steady = (result.get("frame_time_ms") or {}).get("steady") or {}
    row = steady.get("methods", {}).get("as_ccv_t")
    if row and steady.get("size") == "1920x1080":
        # Issue 46: the temporal method's steady 1080p frame within half a second.
        t["as_ccv_t_1080p_s"] = _target(
            row["median_s"],
            0.5,
            "<=",
            min_s=row["min_s"],
            max_s=row["max_s"],
            runs=len(row["runs_s"]),
            backend=steady.get("backend"),
        )
    if "wall_s" in result:
        cpus = result.get("environment", {}).get("cpus")
        t["bench_wall_s"] = _target(result["wall_s"], 900.0, "<=", cpus=cpus)
    return t


def clean_json(obj: Any) -> Any:
    """``obj`` with NumPy scalars as Python numbers, tuples as lists and non-finite floats as None.

    >>> clean_json({"a": float("nan"), 1: (np.float32(0.5), np.int64(2))})
    {'a': None, '1': [0.5, 2]}
    """
    if isinstance(obj, float):
        return None if not math.isfinite(obj) else obj
    if isinstance(obj, dict):
        return {str(k): clean_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [clean_json(v) for v in obj]
    if isinstance(obj, np.generic):
        return clean_json(obj.item())
    return obj


def to_json(data: Any) -> str:
    """The bench's JSON text of ``data`` (:func:`clean_json`, indent 1, UTF-8, final newline)."""
    return json.dumps(clean_json(data), indent=1, ensure_ascii=False) + "\n"


def write_json(path: str | Path, data: Any) -> None:
    """Write :func:`to_json` of ``data`` to ``path`` atomically (folders created)."""
    write_text(path, to_json(data))
