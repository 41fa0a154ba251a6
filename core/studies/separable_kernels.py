"""Separable-SSS kernels: approximation error and per-frame cost (Figure S.3 in numbers).

For every kernel of :data:`cvsss.core.separable.kernels.KERNELS`:

- **error**: the relative L2 (Frobenius) error ``‖R − A‖/‖R‖`` of the kernel's
  2D approximation A against the discrete 2D profile R (the "true kernel"),
  per channel, for each SSS material of the synthetic scene (Burley) and for
  the dipole profile of each measured preset (seeds/004 section G);
- **cost**: wall time of the two convolution passes (``sampling_ms``, median over
  frames) on ``core.synthetic.scene_frame('flash', n, W, H)``, per tap count;
- **PSNR** of the composite against the Monte Carlo reference of the same
  profile (display-referred luminance over SSS pixels, core.metrics.psnr),
  i.e. what the separable approximation costs in image quality.

Run (front-end: ``sss_addon.cli.studies``)::

    cvsss separable-kernels --res 640x360 --frames 3 --out out/separable_kernels

It prints the tables (markdown, :func:`format_tables`) and writes
``separable_kernels.json`` and ``separable_kernels.md`` into ``--out``.
Timings depend on the machine.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..eval.metrics import psnr
from ..method import MethodOptions
from ..methods import make_processor
from ..params import KERNELS, TAP_COUNTS, SeparableParams, SSSParams
from ..profiles import presets
from ..profiles.dipole import DipoleProfile
from ..profiles.factory import frame_profile
from ..separable.kernels import kernel_errors, svd_optimum_errors
from ..synthetic import scene_frame


def _passes(kernel: str, gaussians: int) -> int:
    return 2 * SeparableParams(kernel=kernel, gaussians=gaussians).terms


def run(
    width: int = 640,
    height: int = 360,
    frames: int = 3,
    taps: Sequence[int] = TAP_COUNTS,
    gaussians: int = 4,
    reference_spp: int = 256,
    presets_table: bool = True,
    machine: str = "",
) -> dict:
    """Compute the error, cost and PSNR tables (see module doc).

    Parameters
    ----------
    width, height : int, pixels of the flash frames
    frames : int >= 1, frames timed
    taps : tap counts (each of :data:`cvsss.core.params.TAP_COUNTS`)
    gaussians : int, N of the ``gaussians`` kernel
    reference_spp : int, samples per pixel of the Monte Carlo reference
    presets_table : bool, also the error table of the measured presets
    machine : str, the machine the timings were taken on (recorded as is)
    """
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"frames must be an integer >= 1, got {frames!r}")
    frame_list = [scene_frame("flash", n, width, height) for n in range(1, frames + 1)]
    params = SSSParams(reference_spp=reference_spp)
    profile = frame_profile(frame_list[0], params)
    names = {s.slot: s.name for s in frame_list[0].materials.values()}
    errors = {
        names[s]: {k: v.tolist() for k, v in kernel_errors(profile, s, gaussians=gaussians).items()}
        for s in names
    }
    svd_optimum = {
        names[s]: {f"svd{k}": v.tolist() for k, v in svd_optimum_errors(profile, s).items()}
        for s in names
    }
    ref_proc = make_processor("reference", params)
    refs = [ref_proc.process(f) for f in frame_list]
    cost = []
    for kernel in KERNELS:
        for n in taps:
            sparams = SeparableParams(kernel=kernel, taps=n, gaussians=gaussians)
            proc = make_processor("separable", params, MethodOptions(separable=sparams))
            ms, db = [], []
            for f, ref in zip(frame_list, refs):
                res = proc.process(f)
                ms.append(res.sampling_ms)
                db.append(psnr(res.composite, ref.composite, res.mask, params.exposure))
            cost.append(
                {
                    "kernel": kernel,
                    "taps": n,
                    "passes": _passes(kernel, gaussians),
                    "sampling_ms": float(np.median(ms)),
                    "sampling_ms_min": float(np.min(ms)),
                    "psnr_db": float(np.mean(db)),
                    "sss_pixels": int(res.mask.sum()),
                }
            )
    mc = []
    for method in ("fixed",):  # adaptive methods need a warm history, not a few frames
        proc = make_processor(method, params)
        rows = [proc.process(f) for f in frame_list]
        mc.append(
            {
                "method": method,
                "spp": float(np.mean([r.spp for r in rows])),
                "sampling_ms": float(np.median([r.sampling_ms for r in rows])),
                "sampling_ms_min": float(np.min([r.sampling_ms for r in rows])),
                "psnr_db": float(
                    np.mean(
                        [
                            psnr(r.composite, ref.composite, r.mask, params.exposure)
                            for r, ref in zip(rows, refs)
                        ]
                    )
                ),
            }
        )
    preset_errors = {}
    if presets_table:
        for name in presets.names():
            m = presets.get(name)
            prof = DipoleProfile(
                np.array([[0.0] * 3, m.sigma_a]), np.array([[0.0] * 3, m.sigma_s]), m.eta
            )
            preset_errors[name] = {
                k: float(np.mean(v)) for k, v in kernel_errors(prof, 1, gaussians=gaussians).items()
            }
    return {
        "resolution": [width, height],
        "frames": frames,
        "scene": "flash",
        "reference_spp": reference_spp,
        "gaussians": gaussians,
        "machine": machine,
        "errors": errors,
        "svd_optimum_errors": svd_optimum,
        "cost": cost,
        "monte_carlo": mc,
        "preset_errors": preset_errors,
    }


def format_tables(result: dict) -> str:
    """Markdown tables of a :func:`run` result."""
    mats = list(result["errors"])
    w, h = result["resolution"]
    lines = [
        f"Kernel error (relative L2 vs the discrete 2D profile, R/G/B) and cost at {w}x{h} "
        f"(flash, {result['frames']} frames; PSNR vs the {result['reference_spp']}-spp "
        "Monte Carlo reference)",
        "",
    ]
    head = (
        "| kernel | 1D passes | "
        + " | ".join(f"error {m}" for m in mats)
        + " | "
        + " | ".join(f"ms ({n} taps)" for n in sorted({c["taps"] for c in result["cost"]}))
        + " | "
        + " | ".join(f"PSNR dB ({n})" for n in sorted({c["taps"] for c in result["cost"]}))
        + " |"
    )
    lines += [head, "|" + " --- |" * (head.count("|") - 1)]
    for kernel in dict.fromkeys(c["kernel"] for c in result["cost"]):
        rows = [c for c in result["cost"] if c["kernel"] == kernel]
        errs = " | ".join("/".join(f"{e:.3f}" for e in result["errors"][m][kernel]) for m in mats)
        ms = " | ".join(f"{c['sampling_ms_min']:.0f}" for c in rows)
        db = " | ".join(f"{c['psnr_db']:.2f}" for c in rows)
        lines.append(f"| {kernel} | {rows[0]['passes']} | {errs} | {ms} | {db} |")
    opt = result.get("svd_optimum_errors") or {}
    if opt:
        lines += [
            "",
            "SVD errors above include the energy rescaling (S.4, ‖A‖₁ = ‖R‖₁); without "
            "it (Eckart–Young optimum): "
            + "; ".join(
                f"{m} " + ", ".join(f"{k} {np.mean(v):.3f}" for k, v in opt[m].items())
                for m in mats
            ),
        ]
    lines += [
        "",
        "ms: wall time of the two convolution passes, fastest of the frames (the "
        "median is in the JSON). Burley's profile has one shape (d only scales it), so its "
        "kernel errors are the same for every material and channel.",
    ]
    lines += [
        "",
        "| Monte Carlo | mean spp | sampling ms | PSNR dB |",
        "| --- | ---: | ---: | ---: |",
    ]
    for r in result["monte_carlo"]:
        lines.append(
            f"| {r['method']} | {r['spp']:.1f} | {r['sampling_ms_min']:.0f} | "
            f"{r['psnr_db']:.2f} |"
        )
    if result["preset_errors"]:
        kernels = list(next(iter(result["preset_errors"].values())))
        lines += [
            "",
            "Dipole profile of each measured preset: relative L2 error, mean of R/G/B",
            "",
            "| preset | " + " | ".join(kernels) + " |",
            "| --- |" + " ---: |" * len(kernels),
        ]
        for name, errs in result["preset_errors"].items():
            lines.append(f"| {name} | " + " | ".join(f"{errs[k]:.3f}" for k in kernels) + " |")
    return "\n".join(lines)
