"""Motivating example of P Fig. 2: temporal variance inflates adaptive sample counts.

A 1D surface of ``pixels`` texels (pixel size 1, surface coordinate
x = 4·(i + ½)/pixels ∈ [0, 4]) is lit by

    B(x, t) = I(t)·(b_s + (1 − b_s)(1 − smoothstep(1, 2, x))),

a lit plateau, a shadow gradient over x ∈ [1, 2] and a shadow floor b_s = 0.2
that the same light still reaches (all lighting scales with the one intensity
I(t), the assumption of P Sec. 6.1). ``static``: I ≡ 1; ``dynamic``: the
flash scene's I(t) = sin(2π·5t) + 1 at 60 fps (t = frame/60), 120 frames (2 s).

Scattering is the Burley profile with shape ``d`` in pixels, truncated at 16d
and renormalised as in :class:`cvsss.core.profiles.burley.BurleyProfile`, split at
r0 = ½ pixel (P Eq. 14–16): γ = (T(r0) − T(r_max))/(1 − T(r_max)), and the
distant part f̄ = γ·mean_k B(p ± r_k) with r_k drawn on [r0, r_max] through
the exact inverse (``radius_from_tail``) and a random sign — the 1D version
of the screen-space estimator, B read from the texel the sample lands in
(clamped at the surface's ends). Samples come from the shifted R2 sequence of
:mod:`cvsss.core.sampling.qmc` (first dimension: radius, second: sign),
hashed per (pixel, stream, frame ⊕ seed); all configurations and both
lightings use the same sample at a given (pixel, stream, frame, index), so
their differences are not sampling noise.

Per pixel, SPVG (:func:`cvsss.core.mc.adaptive.sample_counts` /
:func:`~cvsss.core.mc.adaptive.update_history`, :class:`SSSParams` defaults:
σ0² = 1e-4, η = 0.2, κ = 0.2, β = [8, 64]) tracks

``as``      S = f̄;
``as_ocv``  S = f̄ − α_{t−1}·G(t), α from the EMCM (η_cv = 1e-6) of
            Z = [f̄, G(t)] with ε_α = 1e-6 and the bound D of Alg. 2
            (:func:`cvsss.core.mc.control_variates.cv_coefficient`);
``as_ccv``  S = f̄ − G(t) (α ≡ 1, P Sec. 6.3);

with the in-frame constant control G(t) = γ·B(p, t) (P Eq. 30).

``cvsss fig2 --out out`` (front-end and figure: ``sss_addon.cli.studies``)
writes ``fig2.json``, ``fig2_curves.json`` and ``fig2.png`` and prints
:func:`format_table`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..mc.adaptive import sample_counts, update_history
from ..mc.control_variates import cv_coefficient, emcm_step
from ..params import SSSParams
from ..profiles.burley import radius_from_tail, tail
from ..sampling.qmc import pixel_offsets, r2_points

#: Tracked-value configurations → labels.
CONFIGS = {
    "as": "AS: S = f̄",
    "as_ocv": "AS+OCV: S = f̄ − α·G(t)",
    "as_ccv": "AS+CCV: S = f̄ − G(t)",
}
SCENARIOS = ("static", "dynamic")

PIXELS = 256
FRAMES = 120
FPS = 60.0
#: Surface length in x units (the paper's Fig. 2 plots x; gradient at x ∈ [1, 2]).
SURFACE = 4.0
SHADOW_EDGE = (1.0, 2.0)
SHADOW_FLOOR = 0.2
D_PIXELS = 4.0
R0_PIXELS = 0.5
TRUNCATE = 16.0
#: Samples per pixel of the reference f̄ (stratified, both signs).
REFERENCE_SAMPLES = 8192


def intensity(scenario: str, frames: int = FRAMES, fps: float = FPS) -> np.ndarray:
    """Light intensity I per frame: 1 (``static``) or sin(2π·5t) + 1 (``dynamic``).

    Returns
    -------
    (frames,) float64, t = frame/fps.
    """
    if scenario == "static":
        return np.ones(frames)
    if scenario == "dynamic":
        return np.sin(2.0 * np.pi * 5.0 * np.arange(frames) / fps) + 1.0
    raise ValueError(f"scenario must be one of {SCENARIOS}, got {scenario!r}")


def visibility(pixels: int = PIXELS) -> np.ndarray:
    """Unit-intensity lighting B(x)/I of each texel, (pixels,) float64 in [b_s, 1].

    >>> v = visibility(256)
    >>> round(float(v[0]), 3), round(float(v[-1]), 3)
    (1.0, 0.2)
    """
    x = SURFACE * (np.arange(pixels) + 0.5) / pixels
    lo, hi = SHADOW_EDGE
    s = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    smooth = s * s * (3.0 - 2.0 * s)
    return SHADOW_FLOOR + (1.0 - SHADOW_FLOOR) * (1.0 - smooth)


def _tail_bounds(d: float) -> tuple[float, float, float]:
    """T(r0), T(r_max) and γ of the truncated, renormalised profile."""
    t0 = float(tail(R0_PIXELS, d))
    t1 = float(tail(TRUNCATE * d, d))
    return t0, t1, (t0 - t1) / (1.0 - t1)


def _gather(b: np.ndarray, px: np.ndarray, u: np.ndarray, v: np.ndarray, d: float) -> np.ndarray:
    """B at the texels hit by the offsets ±r(u) from texel px (sign from v).

    Parameters
    ----------
    b : (pixels,) float, lighting per texel
    px : integer or float array broadcastable with u, texel index of the centre
    u, v : float arrays in [0, 1), radius and sign dimensions of the samples
    d : float, Burley shape in pixels

    Returns
    -------
    float64 array of the broadcast shape.
    """
    t0, t1, _ = _tail_bounds(d)
    r = radius_from_tail((1.0 - u) * t0 + u * t1, d)
    offset = np.where(v < 0.5, -r, r)
    texel = np.clip(np.floor(px + offset + 0.5), 0, b.size - 1).astype(np.intp)
    return b[texel]


def reference(pixels: int = PIXELS, d: float = D_PIXELS) -> np.ndarray:
    """Unit-intensity distant scattering f̄/I per texel, (pixels,) float64.

    Stratified midpoints in the radius and both signs (``REFERENCE_SAMPLES``).
    """
    _, _, gamma = _tail_bounds(d)
    px = np.arange(pixels)[:, None]
    u = ((np.arange(REFERENCE_SAMPLES // 2) + 0.5) / (REFERENCE_SAMPLES // 2))[None, :]
    b = visibility(pixels)
    total = _gather(b, px, u, 0.25, d).mean(axis=1) + _gather(b, px, u, 0.75, d).mean(axis=1)
    return gamma * total / 2.0


def _simulate(
    lights: dict[str, np.ndarray],
    params: SSSParams,
    streams: int,
    pixels: int,
    d: float,
) -> dict[str, dict[str, np.ndarray]]:
    """Run every configuration under every intensity sequence.

    B = I(t)·visibility, so the unit-intensity texel values the samples hit
    are gathered once per frame and shared by all runs (their prefix sums
    give f̄ for any count).

    Parameters
    ----------
    lights : {scenario: (T,) float, I(t)}, all of the same length T
    params : SSSParams
    streams : independent copies of the surface (rows), each its own samples
    pixels : texels per copy
    d : Burley shape in pixels

    Returns
    -------
    {f"{config}_{scenario}": {"counts": (T, streams, pixels) int32,
    "f_bar": (T, streams, pixels) float64, "alpha": (T, streams, pixels)
    float64}}
    """
    _, _, gamma = _tail_bounds(d)
    n = streams * pixels
    vis = visibility(pixels)
    px = np.tile(np.arange(pixels), streams)
    py = np.repeat(np.arange(streams), pixels)
    k = np.arange(1, params.beta_max + 1)
    rows = np.arange(n)
    gamma_max = np.full(n, gamma)
    n_frames = len(next(iter(lights.values())))

    runs = {}
    for scenario, light in lights.items():
        for config in CONFIGS:
            runs[f"{config}_{scenario}"] = {
                "config": config,
                "light": np.asarray(light, dtype=np.float64),
                "mu": np.zeros(n),
                "var": np.zeros(n),
                "mbar": np.zeros(n),
                "valid": np.zeros(n, dtype=bool),
                "sigma": np.zeros((n, 2, 2)),
                "zeta": np.zeros((n, 2)),
                "counts": np.zeros((n_frames, n), dtype=np.int32),
                "f_bar": np.zeros((n_frames, n)),
                "alpha": np.zeros((n_frames, n)),
            }
    for frame in range(n_frames):
        sx, sy = pixel_offsets(px, py, frame, params.seed)
        u, v = r2_points(sx[:, None], sy[:, None], k[None, :])
        prefix = np.cumsum(_gather(vis, px[:, None], u, v, d), axis=1)
        for run_ in runs.values():
            level = run_["light"][frame]
            m = sample_counts(run_["var"], run_["mbar"], run_["valid"], gamma_max, params)
            taken = prefix[rows, np.maximum(m, 1) - 1]
            f_bar = np.where(m > 0, gamma * level * taken / np.maximum(m, 1), 0.0)
            g_known = gamma * level * vis[px]
            if run_["config"] == "as":
                alpha = np.zeros(n)
            elif run_["config"] == "as_ccv":
                alpha = np.ones(n)
            else:
                sigma, zeta = run_["sigma"], run_["zeta"]
                alpha = cv_coefficient(
                    sigma[:, 0, 1], sigma[:, 1, 1], f_bar, g_known, params.eps_alpha
                )
                z = np.stack([f_bar, g_known], axis=1)
                if frame == 0:
                    run_["zeta"] = z
                else:
                    run_["sigma"], run_["zeta"] = emcm_step(sigma, zeta, z, params.eta_cv)
            tracked = f_bar - alpha * g_known
            run_["mu"], run_["var"], run_["mbar"], run_["valid"] = update_history(
                run_["mu"], run_["var"], run_["mbar"], run_["valid"], tracked, m, params
            )
            run_["counts"][frame] = m
            run_["f_bar"][frame] = f_bar
            run_["alpha"][frame] = alpha
    shape = (n_frames, streams, pixels)
    return {
        key: {name: run_[name].reshape(shape) for name in ("counts", "f_bar", "alpha")}
        for key, run_ in runs.items()
    }


def run(
    seeds: int = 8,
    seed: int = 0,
    params: SSSParams | None = None,
    pixels: int = PIXELS,
    frames: int = FRAMES,
    d: float = D_PIXELS,
) -> dict[str, Any]:
    """Run the motivating example.

    Parameters
    ----------
    seeds : int >= 1
        Independent sample streams (copies of the surface) averaged over.
    seed : int in [0, 2**32)
        Seed of the per-pixel hash (overrides ``params.seed``).
    params : SSSParams, default SSSParams() (the paper's evaluation values)
    pixels, frames : int >= 1
    d : float > 0, Burley shape in pixels

    Returns
    -------
    dict with the mean sample count over all pixels, frames and streams of
    ``as_static``, ``as_dynamic``, ``as_ocv_dynamic``, ``as_ccv_dynamic``,
    ``as_ocv_static``, ``as_ccv_static``; ``increase_as`` =
    as_dynamic/as_static (P Fig. 2: 2.42); ``removed_by_ocv`` /
    ``removed_by_ccv`` = the fraction of the extra samples of AS under dynamic
    lighting (as_dynamic − as_static) that the CV removes (1 = back to the
    static count); ``rmse`` {config_scenario: RMSE of f̄ against the
    reference over all pixels and frames}; ``settings``; and ``curves``
    (per-frame and per-pixel mean counts, the lighting and I(t)).
    """
    for name, value, lo in (("seeds", seeds, 1), ("pixels", pixels, 1), ("frames", frames, 1)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < lo:
            raise ValueError(f"{name} must be an integer >= {lo}, got {value!r}")
    if not (isinstance(d, int | float) and np.isfinite(d) and d > 0):
        raise ValueError(f"d must be a finite number > 0 (pixels), got {d!r}")
    params = (params or SSSParams()).replace(seed=int(seed))
    ref = reference(pixels, d)

    result: dict[str, Any] = {}
    rmse: dict[str, float] = {}
    curves: dict[str, Any] = {
        "x": (SURFACE * (np.arange(pixels) + 0.5) / pixels).tolist(),
        "visibility": visibility(pixels).tolist(),
        "intensity": {s: intensity(s, frames).tolist() for s in SCENARIOS},
        "counts_per_frame": {},
        "counts_per_pixel": {},
        "alpha_per_frame": {},
    }
    lights = {scenario: intensity(scenario, frames) for scenario in SCENARIOS}
    sims = _simulate(lights, params, int(seeds), int(pixels), float(d))
    for scenario, light in lights.items():
        for config in CONFIGS:
            key = f"{config}_{scenario}"
            sim = sims[key]
            counts = sim["counts"].astype(np.float64)
            result[key] = float(counts.mean())
            err = sim["f_bar"] - light[:, None, None] * ref[None, None, :]
            rmse[key] = float(np.sqrt(np.mean(err * err)))
            curves["counts_per_frame"][key] = counts.mean(axis=(1, 2)).tolist()
            curves["counts_per_pixel"][key] = counts.mean(axis=(0, 1)).tolist()
            curves["alpha_per_frame"][key] = sim["alpha"].mean(axis=(1, 2)).tolist()
    extra = result["as_dynamic"] - result["as_static"]
    result["increase_as"] = result["as_dynamic"] / result["as_static"]
    for cv in ("ocv", "ccv"):
        removed = result["as_dynamic"] - result[f"as_{cv}_dynamic"]
        result[f"removed_by_{cv}"] = removed / extra if extra != 0 else float("nan")
    result["rmse"] = rmse
    result["settings"] = {
        "seeds": int(seeds),
        "seed": int(seed),
        "pixels": int(pixels),
        "frames": int(frames),
        "fps": FPS,
        "d_pixels": float(d),
        "r0_pixels": R0_PIXELS,
        "truncate": TRUNCATE,
        "shadow_edge": list(SHADOW_EDGE),
        "shadow_floor": SHADOW_FLOOR,
        "params": params.to_dict(),
    }
    result["curves"] = curves
    return result


def format_table(result: dict[str, Any]) -> str:
    """Markdown table of a :func:`run` result: mean spp and f̄ RMSE per configuration."""
    lines = [
        "| configuration | spp static | spp dynamic | RMSE static | RMSE dynamic |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for config, label in CONFIGS.items():
        cells = [f"{result[f'{config}_{s}']:.2f}" for s in SCENARIOS]
        cells += [f"{result['rmse'][f'{config}_{s}']:.4f}" for s in SCENARIOS]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    s = result["settings"]
    lines += [
        "",
        f"AS under dynamic lighting takes {result['increase_as']:.2f}× the static count "
        f"(P Fig. 2: 2.42×); OCV removes {100 * result['removed_by_ocv']:.0f} % and CCV "
        f"{100 * result['removed_by_ccv']:.0f} % of the extra samples.",
        f"{s['pixels']} pixels × {s['frames']} frames × {s['seeds']} streams (seed {s['seed']}), "
        f"Burley d = {s['d_pixels']:g} px, I(t) = sin(2π·5t) + 1 at {s['fps']:g} fps.",
    ]
    return "\n".join(lines)
