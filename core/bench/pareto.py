"""Section ``pareto``: the speed/accuracy front and the quality calibration."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..backends import select as mc_backend
from ..eval import quality
from ..frame import Frame
from ..io.exr import list_frames, read_frame
from ..method import MethodOptions
from ..methods import METHODS, make_processor
from ..params import KERNELS, PAPER_DEFAULTS, SeparableParams, SSSParams
from .config import ADAPTIVE, BenchConfig, Log, Size, progress, size_key
from .cost import available_backends
from .jobs import Job, run_jobs, run_sequence, summarize, synthetic_frames
from .reference import reference_composites


def separable_kernels() -> tuple[list[tuple[str, SeparableParams]], str]:
    """``[(kernel name, SeparableParams)]`` of every separable kernel, and a note."""
    runs = [(name, SeparableParams(kernel=name)) for name in KERNELS]
    taps = runs[0][1].taps if runs else 0
    return runs, f"{len(runs)} separable kernels ({taps} taps, no jitter)"


# -- the Pareto front and the quality calibration ---------------------------------
def pareto_front(points: Sequence[dict]) -> list[int]:
    """Indices of points no other point beats in both sampling time and PSNR, fastest first.

    >>> pareto_front([{"sampling_ms": 1, "psnr_db": 30}, {"sampling_ms": 2, "psnr_db": 20},
    ...               {"sampling_ms": 3, "psnr_db": 40}])
    [0, 2]
    """
    order = sorted(
        range(len(points)), key=lambda i: (points[i]["sampling_ms"], -points[i]["psnr_db"])
    )
    front, best = [], -math.inf
    for i in order:
        if points[i]["psnr_db"] > best:
            front.append(i)
            best = points[i]["psnr_db"]
    return front


def fixed_time_at(points: Sequence[dict], psnr_db: float) -> tuple[float, bool]:
    """Pass time of ``fixed`` at ``psnr_db``, interpolating log(time) over PSNR.

    Returns (ms, extrapolated). The fixed curve is made monotone (best time
    for at least that PSNR) before interpolating.
    """
    fx = sorted((p for p in points if p["method"] == "fixed"), key=lambda p: p["psnr_db"])
    if len(fx) < 2:
        return math.nan, True
    ps = np.array([p["psnr_db"] for p in fx])
    lt = np.log([p["sampling_ms"] for p in fx])
    lt = np.minimum.accumulate(lt[::-1])[::-1]
    if ps[0] <= psnr_db <= ps[-1]:
        return float(np.exp(np.interp(psnr_db, ps, lt))), False
    i = (0, 1) if psnr_db < ps[0] else (-2, -1)
    slope = (lt[i[1]] - lt[i[0]]) / (ps[i[1]] - ps[i[0]])
    return float(np.exp(lt[i[0]] + slope * (psnr_db - ps[i[0]]))), True


def section_pareto(
    cfg: BenchConfig, log: Log = None, start: float | None = None, passes: Path | None = None
) -> dict:
    """Pareto points, the quality calibration and the quality checks."""
    base = SSSParams(seed=cfg.seed)
    if passes is not None:
        listed = list_frames(passes)[: cfg.warmup + cfg.pareto_frames]
        frames = [read_frame(p, number=n) for n, p in listed]
        scene = f"pass directory {passes}"
        size = (frames[0].shape[1], frames[0].shape[0])
    else:
        size = cfg.pareto_size
        frames = synthetic_frames(cfg.scene, size, cfg.warmup + cfg.pareto_frames)
        scene = f"synthetic {cfg.scene}"
    warm = min(cfg.warmup, max(len(frames) - 1, 0))
    ref, ref_info = reference_composites(frames, base, log, start)
    measured = frames[warm:]
    refs = [ref(i) for i in range(len(frames))]  # PSNR of every job compares with these
    jobs: list[Job] = []
    meta: list[dict] = []

    def add(
        method: str,
        params: SSSParams,
        label: str,
        family: str,
        param: str,
        value: Any,
        separable: SeparableParams | None = None,
    ) -> None:
        # Methods without history skip the warm-up frames: they would only cost time.
        first = 0 if METHODS[method].adaptive else warm
        jobs.append(
            Job(
                label,
                method,
                params,
                frames.__getitem__,
                refs.__getitem__,
                first=first,
                record_from=warm,
                separable=separable,
                # The swept points carry the timing figures; the extra calibration
                # points only need PSNR and spp (deterministic), so run them once.
                repeats=cfg.repeats if family == "sweep" else 1,
            )
        )
        meta.append(
            {
                "label": label,
                "method": method,
                "family": family,
                "param": param,
                "value": value,
                "beta_min": params.beta_min if METHODS[method].adaptive else None,
            }
        )

    for n in cfg.fixed_spp:
        add("fixed", base.replace(fixed_spp=n), f"fixed N={n}", "sweep", "fixed_spp", n)
    for method in ADAPTIVE:
        # (σ0², β_min or None for the default, family)
        sweeps = [(s0, None, "sweep") for s0 in cfg.sigmas]
        sweeps += [(s0, None, "calibration") for s0 in cfg.calib_extra_sigmas]
        sweeps += [(s0, bm, "calibration") for bm, sig in cfg.calib_families for s0 in sig]
        for s0, beta_min, family in sweeps:
            params = base.replace(target_variance=s0)
            label = f"{method} σ0²={s0:g}"
            if beta_min is not None:
                params = params.replace(beta_min=beta_min)
                label += f" β_min={beta_min}"
            add(method, params, label, family, "target_variance", s0)
    # The same sweep on the other backends: same samples (same spp and PSNR), other times.
    default_backend = mc_backend.resolve("auto")
    others = [b for b in available_backends(cfg) if b != default_backend]
    n_default = len(jobs)
    for b in others:
        for job, m in list(zip(jobs[:n_default], meta[:n_default])):
            if m["family"] == "sweep":
                jobs.append(
                    dataclasses.replace(job, label=f"{job.label} [{b}]", records=[], last=None)
                )
                jobs[-1].params = job.params.replace(backend=b)
                meta.append({**m, "label": jobs[-1].label, "backend": b})
    extra = (jobs[n_default:], meta[n_default:])
    del jobs[n_default:], meta[n_default:]
    sep_runs, sep_note = separable_kernels()
    for name, sparams in sep_runs:
        try:  # a kernel failing on this scene is reported, not fatal
            make_processor("separable", base, MethodOptions(separable=sparams)).process(frames[0])
        except Exception as exc:
            sep_note += f"; separable {name} failed: {type(exc).__name__}: {exc}"
            continue
        add("separable", base, f"separable {name}", "sweep", "kernel", name, separable=sparams)
    progress(
        log,
        start,
        f"{sep_note}; running {len(jobs) + len(extra[0])} configurations interleaved over "
        f"{len(frames)} frames",
    )
    run_jobs(jobs + extra[0], len(frames))
    by_backend: dict[str, list[dict]] = {b: [] for b in others}
    for job, m in zip(*extra):
        s = summarize(job.records)
        by_backend[m["backend"]].append({**m, **s})
    points: list[dict] = []
    for job, m in zip(jobs, meta):
        s = summarize(job.records)
        points.append(
            {
                **m,
                **s,
                "per_frame": [[r["samples"], r["sampling_ms"], r["psnr_db"]] for r in job.records],
            }
        )
        progress(
            log,
            start,
            f"pareto {m['label']:<30} {s['spp']:6.2f} spp "
            f"{s['sampling_ms']:8.2f} ms {s['psnr_db']:6.2f} dB",
        )
    front = set(pareto_front(points))
    for i, p in enumerate(points):
        p["front"] = i in front
        p["backend"] = default_backend
    # Per backend, the Monte Carlo sweep (separable does not sample) and its own front.
    by_backend = {
        default_backend: [p for p in points if p["family"] == "sweep"],
        **by_backend,
    }
    for pts in by_backend.values():
        mc = [p for p in pts if p["method"] != "separable"]
        fr = set(pareto_front(mc))
        for i, p in enumerate(mc):
            p["front_backend"] = i in fr

    calibration = calibration_from(points, cfg, scene, size, len(measured), warm)
    cal = quality.Calibration.from_dict(calibration)
    checks = quality_checks(cfg, cal, frames, ref, warm, base, log, start)

    default = next(
        (
            p
            for p in points
            if p["method"] == "as_ccv"
            and p["family"] == "sweep"
            and p["value"] == PAPER_DEFAULTS["target_variance"]
        ),
        None,
    )
    equal_psnr = []
    for p in points:
        if p["method"] == "as_ccv" and p["family"] == "sweep":
            t_fixed, extra = fixed_time_at(points, p["psnr_db"])
            equal_psnr.append(
                {
                    "value": p["value"],
                    "psnr_db": p["psnr_db"],
                    "sampling_ms": p["sampling_ms"],
                    "fixed_ms_at_equal_psnr": t_fixed,
                    "ratio": p["sampling_ms"] / t_fixed,
                    "extrapolated": extra,
                }
            )
    return {
        "scene": scene,
        "size": size_key(size),
        "frames": len(measured),
        "warmup": warm,
        "reference": ref_info,
        "points": points,
        "backend_default": default_backend,
        "by_backend": {
            b: [
                {k: p[k] for k in ("label", "method", "value", "spp", "sampling_ms", "psnr_db")}
                | {"front": p.get("front_backend", False)}
                for p in pts
            ]
            for b, pts in by_backend.items()
        },
        "separable": sep_note,
        "front": [p["label"] for p in points if p["front"]],
        "as_ccv_vs_fixed": equal_psnr,
        "as_ccv_default": None if default is None else default["label"],
        "calibration": calibration,
        "quality_checks": checks,
    }


def calibration_from(
    points: Sequence[dict], cfg: BenchConfig, scene: str, size: Size, frames: int, warm: int
) -> dict:
    """The quality calibration (``quality_calibration.json`` body) from Pareto points.

    ``fixed`` is one family over N; each adaptive method has one σ0² family
    per β_min, largest β_min first.
    """
    curves: dict[str, list[dict]] = {}

    def family(ps: list[dict], param: str, fixed: dict) -> dict:
        return {
            "param": param,
            "values": [p["value"] for p in ps],
            "psnr_db": [p["psnr_db"] for p in ps],
            "spp": [p["spp"] for p in ps],
            "sampling_ms": [p["sampling_ms"] for p in ps],
            "fixed": fixed,
        }

    fx = [p for p in points if p["method"] == "fixed"]
    if fx:
        curves["fixed"] = [family(fx, "fixed_spp", {})]
    for method in ADAPTIVE:
        fams: dict[int, list[dict]] = {}
        for p in points:
            if p["method"] == method and p["param"] == "target_variance":
                fams.setdefault(p["beta_min"], []).append(p)
        curves[method] = [
            family(ps, "target_variance", {"beta_min": bm})
            for bm, ps in sorted(fams.items(), reverse=True)
        ]
    defaults = {
        k: v
        for k, v in SSSParams(seed=cfg.seed).to_dict().items()
        if k not in ("target_variance", "beta_min", "fixed_spp")
    }
    return quality.calibration_dict(
        curves,
        {
            "scene": scene,
            "resolution": size_key(size),
            "frames": frames,
            "warmup_frames": warm,
            "measured": "mean luminance PSNR over SSS pixels against the 1024-spp reference "
            "(display-referred) and mean spp, frames after the warm-up",
            "params": defaults,
        },
    )


def quality_checks(
    cfg: BenchConfig,
    cal: quality.Calibration,
    frames: Sequence[Frame],
    ref: Callable[[int], np.ndarray],
    warm: int,
    base: SSSParams,
    log: Log = None,
    start: float | None = None,
) -> dict:
    """Ask the fresh calibration for targets, then measure on an independent seed."""
    out: dict[str, Any] = {"method": cfg.check_method, "seed": cfg.check_seed}
    base = base.replace(seed=cfg.check_seed)

    def measure(
        target: quality.QualityTarget, seq, reference
    ) -> tuple[quality.QualityChoice, dict]:
        choice = quality.choose(target, cfg.check_method, cal)
        recs, _ = run_sequence(
            seq, cfg.check_method, base.replace(**choice.changes), reference=reference, skip=warm
        )
        return choice, summarize(recs)

    for key, value in (("psnr", cfg.check_psnr_db), ("spp", cfg.check_spp)):
        target = quality.QualityTarget(key, value)
        choice, s = measure(target, frames, ref)
        got = s["psnr_db"] if key == "psnr" else s["spp"]
        out[key] = {
            "target": target.value,
            "choice": choice.changes,
            "clamped": choice.clamped,
            "predicted_psnr_db": choice.predicted_psnr_db,
            "predicted_spp": choice.predicted_spp,
            "measured_psnr_db": s["psnr_db"],
            "measured_spp": s["spp"],
            "error": got - target.value,
        }
        progress(
            log,
            start,
            f"quality {target}: {choice.describe()}; measured "
            f"{s['psnr_db']:.2f} dB at {s['spp']:.2f} spp",
        )
    if cfg.transfer_size is not None:
        tf = synthetic_frames(cfg.scene, cfg.transfer_size, len(frames))
        tref, _ = reference_composites(tf, base.replace(seed=cfg.seed))
        choice, s = measure(quality.QualityTarget("psnr", cfg.check_psnr_db), tf, tref)
        out["transfer"] = {
            "size": size_key(cfg.transfer_size),
            "target": cfg.check_psnr_db,
            "choice": choice.changes,
            "measured_psnr_db": s["psnr_db"],
            "measured_spp": s["spp"],
            "error": s["psnr_db"] - cfg.check_psnr_db,
        }
        progress(
            log,
            start,
            f"quality {cfg.check_psnr_db:g} dB at {size_key(cfg.transfer_size)}: "
            f"measured {s['psnr_db']:.2f} dB",
        )
    try:
        shipped = quality.load_calibration()
        sc = quality.choose(
            quality.QualityTarget("psnr", cfg.check_psnr_db), cfg.check_method, shipped
        )
        out["shipped_choice"] = {"choice": sc.changes, "predicted_psnr_db": sc.predicted_psnr_db}
    except (FileNotFoundError, ValueError) as exc:
        out["shipped_choice"] = {"error": str(exc)}
    return out
