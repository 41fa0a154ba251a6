"""float16 history: how far counts and α drift from a float32 history.

The paper keeps the per-pixel history in RGBA16F render targets. This study
runs the synthetic ``flash`` sequence (the paper's flash scene,
``I(t) = sin(2π·5t) + 1`` at 60 fps, :mod:`cvsss.core.synthetic`) through
the Monte Carlo processor (:func:`cvsss.core.methods.make_processor`) three
times per adaptive method, in lockstep, with the same samples (fixed seed):

``float32``
    the reference history;
``float16``
    half-precision storage as shipped: Σ stored as Σ/η_cv, σ² as σ²/σ0²
    (:mod:`cvsss.core.mc.history`);
``float16_unscaled``
    half-precision storage without those scales (what a naive RGBA16F port
    does).

Per frame it compares each float16 run with the float32 run: mean spp, the
mean and share of per-pixel count differences over SSS pixels, and the mean
and largest |Δα| over pixels that took samples in both. It also measures the
underflow directly: the share of the float32 run's covariances Σ_yy that
would flush to zero in float16 with and without the 1/η_cv scale, and, for
σ0² at the limits of its range, the mean spp of the three storages.

A long run (default 6000 frames, the flash period repeated at 48x27) shows
how α drifts once the float16 Σ/η_cv is large enough that part of each
frame's increment is rounded away.

Command (front-end: ``sss_addon.cli.studies``; writes ``OUT/fp16.json``)::

    cvsss fp16 --out out    # 300 frames, 96x54, + 6000-frame run
"""

from __future__ import annotations

import copy
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..frame import Frame
from ..mc.history import History
from ..methods import make_processor
from ..params import SSSParams
from ..synthetic import scene_frame

VARIANTS = ("float32", "float16", "float16_unscaled")
METHODS = ("as", "as_ocv", "as_ccv")
#: σ0² values of the variance-scaling measurement (limits of the tested range).
TARGET_VARIANCES = (1e-12, 1e-4, 1e6)
FLOAT16_TINY = float(np.finfo(np.float16).smallest_subnormal)


def _processor(method: str, params: SSSParams, variant: str, shape: tuple[int, int]):
    precision = "float32" if variant == "float32" else "float16"
    proc = make_processor(method, params.replace(history_precision=precision))
    if variant == "float16_unscaled":
        proc.history = History.empty(
            shape, "float16", params.eta_cv, params.target_variance, scaled=False
        )
    return proc


def _zero_share(history: History, mask: np.ndarray) -> float:
    """Share of J-valid SSS pixels whose stored Σ_yy is exactly 0."""
    cvv = history.cv_valid & mask
    return float(np.mean(history.buffers["syy"][cvv] == 0)) if cvv.any() else float("nan")


def _lost_share(h32: History, h16: History, mask: np.ndarray, eps_alpha: float) -> float:
    """Share of significant float32 Σ_yy (≥ 1 % of ε_α, so they move α) stored as 0."""
    both = h32.cv_valid & h16.cv_valid & mask
    significant = h32.buffers["syy"][both].astype(np.float64) >= max(0.01 * eps_alpha, 1e-30)
    if not significant.any():
        return float("nan")
    return float(np.mean(h16.buffers["syy"][both][significant] == 0))


def _summary(rows: list[dict[str, float]], key: str) -> float:
    values = [r[key] for r in rows if r[key] == r[key]]
    return float(np.mean(values)) if values else float("nan")


def drift(frames: Sequence[Frame], method: str, params: SSSParams) -> dict[str, Any]:
    """Run the three storages of :data:`VARIANTS` in lockstep and compare.

    Parameters
    ----------
    frames : sequence of Frame, the sequence (in order)
    method : {"as", "as_ocv", "as_ccv"}
    params : SSSParams (history_precision is overridden)

    Returns
    -------
    dict with ``summary`` (per float16 variant: mean spp of both runs, spp
    difference, count and α differences, Σ underflow share) and
    ``per_frame`` (the same per frame).
    """
    shape = frames[0].shape
    procs = {v: _processor(method, params, v, shape) for v in VARIANTS}
    per_frame: dict[str, list[dict[str, float]]] = {v: [] for v in VARIANTS[1:]}
    syy32_zero: list[float] = []
    for frame in frames:
        res = {v: procs[v].process(frame) for v in VARIANTS}
        base = res["float32"]
        mask = base.mask
        m32 = base.counts[mask].astype(np.int64)
        for v in VARIANTS[1:]:
            r = res[v]
            m16 = r.counts[mask].astype(np.int64)
            both = (m32 > 0) & (m16 > 0)
            da = np.abs(r.alpha[mask][both].astype(np.float64) - base.alpha[mask][both])
            row = {
                "frame": frame.number,
                "spp32": base.spp,
                "spp16": r.spp,
                "dcount_mean": float(np.mean(np.abs(m16 - m32))) if m32.size else 0.0,
                "dcount_share": float(np.mean(m16 != m32)) if m32.size else 0.0,
                "dalpha_mean": float(da.mean()) if da.size else float("nan"),
                "dalpha_max": float(da.max()) if da.size else float("nan"),
                "alpha16_mean": float(r.alpha[mask][m16 > 0].mean())
                if both.any()
                else float("nan"),
                "alpha32_mean": float(base.alpha[mask][m32 > 0].mean())
                if both.any()
                else float("nan"),
            }
            if method == "as_ocv":
                row["syy_zero_share"] = _zero_share(procs[v].history, mask)
                row["syy_lost_share"] = _lost_share(
                    procs["float32"].history, procs[v].history, mask, params.eps_alpha
                )
            per_frame[v].append(row)
        if method == "as_ocv":
            syy32_zero.append(_zero_share(procs["float32"].history, mask))
    summary: dict[str, Any] = {}
    n = len(frames)
    third = max(n // 3, 1)
    for v, rows in per_frame.items():
        spp32 = np.array([r["spp32"] for r in rows])
        spp16 = np.array([r["spp16"] for r in rows])
        rel = np.abs(spp16 - spp32) / np.maximum(spp32, 1e-12)
        s = {
            "spp_float32": float(spp32.mean()),
            "spp_float16": float(spp16.mean()),
            "spp_rel_diff": float((spp16.mean() - spp32.mean()) / max(spp32.mean(), 1e-12)),
            "spp_rel_diff_max_frame": float(rel.max()),
            "dcount_mean": _summary(rows, "dcount_mean"),
            "dcount_share": _summary(rows, "dcount_share"),
            "dcount_mean_first_third": _summary(rows[:third], "dcount_mean"),
            "dcount_mean_last_third": _summary(rows[-third:], "dcount_mean"),
            "dalpha_mean": _summary(rows, "dalpha_mean"),
            "dalpha_max": float(np.nanmax([r["dalpha_max"] for r in rows] + [0.0])),
            "alpha_mean_float16": _summary(rows, "alpha16_mean"),
            "alpha_mean_float32": _summary(rows, "alpha32_mean"),
        }
        if method == "as_ocv":
            s["syy_stored_zero_share"] = _summary(rows, "syy_zero_share")
            s["syy_stored_zero_share_float32"] = float(np.nanmean(syy32_zero))
            s["syy_significant_lost_share"] = _summary(rows, "syy_lost_share")
        summary[v] = s
    out: dict[str, Any] = {"summary": summary, "per_frame": per_frame}
    out["history_bytes"] = {v: int(procs[v].history.nbytes()) for v in VARIANTS}
    return out


def variance_scaling(
    frames: Sequence[Frame], params: SSSParams, method: str = "as"
) -> dict[str, dict[str, float]]:
    """Mean spp of each storage for σ0² at the limits of its range.

    The counts depend on σ²/σ0² only, so scaling the exposure by
    sqrt(σ0²/σ0²_default) leaves them unchanged in exact arithmetic: any
    difference between the σ0² rows of one storage is a precision effect.
    """
    out: dict[str, dict[str, float]] = {}
    for s0 in TARGET_VARIANCES:
        exposure = params.exposure * float(np.sqrt(s0 / params.target_variance))
        p = params.replace(target_variance=s0, exposure=exposure)
        procs = {v: _processor(method, p, v, frames[0].shape) for v in VARIANTS}
        spp = {v: [] for v in VARIANTS}
        for frame in frames:
            for v in VARIANTS:
                spp[v].append(procs[v].process(frame).spp)
        row: dict[str, float] = {v: float(np.mean(spp[v])) for v in VARIANTS}
        row["exposure"] = exposure
        with np.errstate(over="ignore"):
            row["sigma0_stored_unscaled_float16"] = float(np.float16(s0))
        out[f"{s0:g}"] = row
    return out


def long_run(
    frames: int,
    params: SSSParams,
    width: int = 48,
    height: int = 27,
    report: Sequence[int] = (100, 300, 1000, 2000, 3000, 6000, 10000),
) -> list[dict[str, float]]:
    """α drift of the online CV over a long run (the flash period repeated).

    Σ/η_cv grows like n·E[(ΔZ)²] over the first 1/η_cv frames; once it is
    ~2000 times one frame's increment, float16 rounds part of each increment
    away, so the float16 Σ lags behind and α drifts slowly.
    """
    period = [scene_frame("flash", n, width, height) for n in range(1, 13)]  # 5 Hz at 60 fps
    procs = {v: _processor("as_ocv", params, v, period[0].shape) for v in VARIANTS[:2]}
    rows = []
    for n in range(1, frames + 1):
        frame = copy.copy(period[(n - 1) % len(period)])
        frame.number = n
        res = {v: procs[v].process(frame) for v in procs}
        if n in report or n == frames:
            a, b = res["float32"], res["float16"]
            both = a.mask & (a.counts > 0) & (b.counts > 0)
            da = np.abs(a.alpha[both].astype(np.float64) - b.alpha[both])
            idx = np.flatnonzero(both)
            s32 = procs["float32"].history.read("syy", idx)
            s16 = procs["float16"].history.read("syy", idx)
            rows.append(
                {
                    "frame": n,
                    "spp_float32": a.spp,
                    "spp_float16": b.spp,
                    "dalpha_mean": float(da.mean()) if da.size else float("nan"),
                    "dalpha_max": float(da.max()) if da.size else float("nan"),
                    "syy_ratio_median": float(np.median(s16[s32 > 0] / s32[s32 > 0]))
                    if np.any(s32 > 0)
                    else float("nan"),
                }
            )
    return rows


def measure(
    frames: int = 300,
    width: int = 96,
    height: int = 54,
    methods: Sequence[str] = METHODS,
    params: SSSParams | None = None,
    scaling_frames: int = 60,
    long_frames: int = 0,
) -> dict[str, Any]:
    """The whole study (see module docstring); returns the JSON-ready result.

    Parameters
    ----------
    frames : int >= 2, frames of the flash sequence
    width, height : int >= 1, pixels
    methods : non-empty subset of :data:`METHODS`
    params : SSSParams, default the paper's (history_precision is overridden)
    scaling_frames : int, frames of the σ0² measurement (:func:`variance_scaling`)
    long_frames : int, frames of :func:`long_run` (0: skipped)
    """
    if frames < 2:
        raise ValueError(f"frames must be >= 2, got {frames}")
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ValueError(f"methods must be a subset of {', '.join(METHODS)}, got {methods!r}")
    params = params or SSSParams()
    seq = [scene_frame("flash", n, width, height) for n in range(1, frames + 1)]
    t0 = time.perf_counter()
    result: dict[str, Any] = {
        "scene": "flash",
        "frames": frames,
        "width": width,
        "height": height,
        "params": params.to_dict(),
        "float16_smallest_subnormal": FLOAT16_TINY,
        "float16_max": float(np.finfo(np.float16).max),
        "drift": {},
    }
    for method in methods:
        result["drift"][method] = drift(seq, method, params)
    result["variance_scaling"] = variance_scaling(seq[:scaling_frames], params)
    if long_frames:
        result["long_run"] = long_run(long_frames, params)
    result["seconds"] = round(time.perf_counter() - t0, 2)
    return result


def format_table(result: dict[str, Any]) -> str:
    """Human-readable summary of :func:`measure`."""
    lines = [
        f"float16 vs float32 history, {result['scene']} {result['width']}x{result['height']}, "
        f"{result['frames']} frames",
        f"{'method':8} {'storage':17} {'spp32':>7} {'spp16':>7} {'Δspp':>7} "
        f"{'|Δm|':>6} {'m≠':>6} {'|Δα|':>8} {'max|Δα|':>8} {'Σ lost':>6}",
    ]
    for method, d in result["drift"].items():
        for v, s in d["summary"].items():
            lines.append(
                f"{method:8} {v:17} {s['spp_float32']:7.2f} {s['spp_float16']:7.2f} "
                f"{100 * s['spp_rel_diff']:+6.2f}% {s['dcount_mean']:6.3f} "
                f"{100 * s['dcount_share']:5.1f}% {s['dalpha_mean']:8.2e} {s['dalpha_max']:8.2e} "
                + (
                    f"{100 * s['syy_significant_lost_share']:5.1f}%"
                    if "syy_significant_lost_share" in s
                    else "     -"
                )
            )
        s = d["summary"]["float16"]
        if "syy_stored_zero_share_float32" in s:
            lines.append(
                "  Σ lost: share of float32 Σ_yy ≥ 0.01·ε_α stored as 0 in float16; "
                "stored exactly 0:"
            )
            lines.append(
                f"  {method}: Σ_yy stored as exactly 0 (J-valid pixels): float32 "
                f"{100 * s['syy_stored_zero_share_float32']:.1f}%, float16 "
                f"{100 * s['syy_stored_zero_share']:.1f}%, float16 unscaled "
                f"{100 * d['summary']['float16_unscaled']['syy_stored_zero_share']:.1f}%"
            )
    lines.append("mean spp (as), σ0² with exposure ∝ σ0 (same counts in exact arithmetic):")
    lines.append("  float32 / float16 / float16 unscaled")
    for s0, v in result["variance_scaling"].items():
        lines.append(
            f"  σ0² = {s0:>6}: {v['float32']:7.2f} / {v['float16']:7.2f} / "
            f"{v['float16_unscaled']:7.2f}"
        )
    if result.get("long_run"):
        lines.append(
            "long run, as_ocv, flash period repeated (48x27): frame, spp32, spp16, "
            "mean |Δα|, max |Δα|, median Σ16/Σ32"
        )
        for r in result["long_run"]:
            lines.append(
                f"  {r['frame']:6d} {r['spp_float32']:7.3f} {r['spp_float16']:7.3f} "
                f"{r['dalpha_mean']:9.2e} {r['dalpha_max']:9.2e} {r['syy_ratio_median']:6.3f}"
            )
    return "\n".join(lines)
