"""The demo's figures checked against the targets of the issues (CV saves samples,
faithful to Cycles, temporal reuse), and why a missed ground-truth target is missed."""

from __future__ import annotations

import math

import numpy as np

#: Targets of the demo issue: (min spp ratio AS / AS+CCV, max PSNR loss dB).
TARGETS = {"flash": (1.8, 2.0), "regular": (1.3, 1.5), "boids": (1.3, 1.5)}
#: Worst frame's spp under CV at most this times its median.
STEADY = 1.5


def check_targets(summary: dict) -> list[dict]:
    """Measured against the demo targets: CV saves samples, costs little PSNR, is steady."""
    rows = []
    for scene, s in summary.items():
        if not {"as", "as_ccv"} <= set(s):
            continue
        min_ratio, max_loss = TARGETS.get(scene, TARGETS["regular"])
        ratio = s["as"]["spp"] / max(s["as_ccv"]["spp"], 1e-12)
        loss = s["as"]["psnr_db"] - s["as_ccv"]["psnr_db"]
        rows.append(
            {
                "scene": scene,
                "check": f"spp AS / AS+CCV >= {min_ratio}",
                "value": ratio,
                "met": bool(ratio >= min_ratio),
            }
        )
        rows.append(
            {
                "scene": scene,
                "check": f"PSNR loss AS -> AS+CCV <= {max_loss} dB",
                "value": loss,
                "met": bool(loss <= max_loss),
            }
        )
        for m in ("as_ocv", "as_ccv", "as"):
            if m in s:
                steady = s[m]["spp_max"] / max(s[m]["spp_median"], 1e-12)
                rows.append(
                    {
                        "scene": scene,
                        "check": f"{m}: max spp / median spp <= {STEADY}",
                        "value": steady,
                        "met": bool(steady <= STEADY) if m != "as" else None,
                    }
                )
    return rows


def _check(scene: str, text: str, value: float, met) -> dict:
    return {"scene": scene, "check": text, "value": value, "met": met}


def _gap(s: dict, a: str, b: str, key: str) -> float:
    return s[a][key] - s[b][key] if {a, b} <= set(s) else math.nan


def _met(value: float, ok: bool):
    return None if value != value else bool(ok)


def check_truth_targets(summary: dict, extras: dict) -> list[dict]:
    """The figures of the issue "Faithful to Cycles", against Cycles ground truth."""
    rows = []
    for scene, s in summary.items():
        if "as_ccv" not in s or s["as_ccv"]["psnr_gt_db"] != s["as_ccv"]["psnr_gt_db"]:
            continue
        v = _gap(s, "as_ccv", "none", "psnr_gt_warm_db")
        rows.append(_check(scene, "as_ccv - none, warm frames (dB) >= 3", v, _met(v, v >= 3)))
        v = _gap(s, "as_ccv", "separable", "psnr_gt_warm_db")
        rows.append(_check(scene, "as_ccv - separable, warm frames (dB) >= 2", v, _met(v, v >= 2)))
        if {"as_ccv", "none"} <= set(s):
            per = np.array(s["as_ccv"]["psnr_gt_frames"]) - np.array(s["none"]["psnr_gt_frames"])
            v = float(per.min()) if per.size else math.nan
            rows.append(
                _check(scene, "every GT frame: as_ccv - none (dB) >= 0", v, _met(v, v >= 0))
            )
        v = s["as_ccv"].get("rim_outer_ratio", math.nan) - 1.0
        rows.append(
            _check(
                scene,
                "outer silhouette luminance as_ccv / GT - 1, within ±0.03",
                v,
                _met(v, abs(v) <= 0.03),
            )
        )
        v = s["as_ccv"].get("rim_contact_ratio", math.nan) - 1.0
        rows.append(_check(scene, "contact edges: as_ccv / GT - 1 (reported)", v, None))
        wax = extras.get(scene, {}).get("half_weight")
        if wax:
            v = wax["as_ccv"] - wax["none"]
            rows.append(
                _check(
                    scene, "Subsurface Weight 0.5 (wax): as_ccv - none (dB) > 0", v, _met(v, v > 0)
                )
            )
        et = extras.get(scene, {}).get("equal_time")
        if et:
            mine = next((r for r in et if r["what"].endswith("+ OIDN + as_ccv")), None)
            cycles = [
                r for r in et if r["what"].startswith("Cycles") and r["what"].endswith("OIDN")
            ]
            if mine and cycles:
                affordable = [r for r in cycles if r["seconds"] <= mine["seconds"]] or [
                    min(cycles, key=lambda r: r["seconds"])
                ]
                best = max(affordable, key=lambda r: r["psnr_gt_db"])
                v = mine["psnr_gt_db"] - best["psnr_gt_db"]
                rows.append(
                    _check(
                        scene,
                        f"denoised passes + as_ccv - {best['what']} (dB, equal time) >= -1",
                        v,
                        _met(v, v >= -1),
                    )
                )
    return rows


def check_temporal_targets(summary: dict, extras: dict) -> list[dict]:
    """The figures of the issue "Temporal reuse guided by the control variate"."""
    rows = []
    for scene, s in summary.items():
        if not {"as_ccv", "as_ccv_t"} <= set(s):
            continue
        v = _gap(s, "as_ccv_t", "as_ccv", "psnr_db")
        rows.append(
            _check(scene, "as_ccv_t - as_ccv, mean PSNR self (dB) >= 3", v, _met(v, v >= 3))
        )
        v = _gap(s, "as_ccv_t", "as_ccv", "psnr_gt_db")
        rows.append(_check(scene, "as_ccv_t - as_ccv vs Cycles GT (dB, for scale)", v, None))
        v = _gap(s, "as_ccv_t", "as_ccv", "psnr_switch_db")
        rows.append(
            _check(
                scene,
                "frames after a flash/switch: as_ccv_t - as_ccv (dB) >= -0.5",
                v,
                _met(v, v >= -0.5),
            )
        )
        v = _gap(s, "as_t", "as_ccv", "psnr_switch_db")
        rows.append(
            _check(scene, "frames after a flash/switch: as_t - as_ccv (dB, plain lag)", v, None)
        )
        v = (
            s["as_ccv"]["flicker"] / s["as_ccv_t"]["flicker"]
            if s["as_ccv_t"]["flicker"]
            else math.nan
        )
        rows.append(_check(scene, "flicker as_ccv / as_ccv_t >= 2", v, _met(v, v >= 2)))
        band = extras.get(scene, {}).get("shadow_band")
        if band:
            v = band["as_ccv_t"] - band["as_ccv"]
            rows.append(
                _check(
                    scene,
                    "moving-shadow band: as_ccv_t - as_ccv (dB) >= -0.5",
                    v,
                    _met(v, v >= -0.5),
                )
            )
    return rows


def truth_reasons(summary: dict, extras: dict, rows: list[dict]) -> list[str]:
    """Why each missed ground-truth target is missed, with the figure that shows it.

    Every miss of :func:`check_truth_targets` is measured against what the
    1024-spp ``reference`` reaches on the same passes: where even that
    estimate, free of Monte Carlo noise, falls short, the rest is model error
    (light on surface the camera does not see); where it does not, the miss is
    our noise at the default σ0².
    """
    lines = []
    for r in rows:
        if r["met"] is not False:
            continue
        s = summary[r["scene"]]
        ref = s.get("reference", {})
        if r["check"].startswith("as_ccv - separable"):
            room = _gap(s, "reference", "separable", "psnr_gt_warm_db")
            noise = _gap(s, "reference", "as_ccv", "psnr_gt_warm_db")
            temporal = _gap(s, "as_ccv_t", "separable", "psnr_gt_warm_db")
            room_text = (
                "so the model has the room"
                if room >= 2
                else "so even without noise the model falls short"
            )
            why = (
                f"the noise-free 1024-spp reference is {room:+.2f} dB from separable, "
                f"{room_text}; as_ccv's Monte Carlo noise at this σ0² costs {noise:.2f} dB "
                f"(a lower σ0² buys some back, see the quality knob), and as_ccv_t, which "
                f"averages it over frames, is {temporal:+.2f} dB from separable"
            )
        elif r["check"].startswith("outer silhouette"):
            v = ref.get("rim_outer_ratio", math.nan) - 1.0
            why = (
                f"the 1024-spp reference's outer rim is {v:+.3f} too: Cycles integrates the "
                "object's hidden back, which screen space cannot see (README, Hidden Light)"
            )
        elif r["check"].startswith("denoised passes"):
            v = ref.get("psnr_gt_db", math.nan)
            rows_et = extras.get(r["scene"], {}).get("equal_time") or []
            cycles = max(
                (e["psnr_gt_db"] for e in rows_et if e["what"].startswith("Cycles")),
                default=math.nan,
            )
            why = (
                f"the 1024-spp reference on the same (undenoised) passes reaches {v:.2f} dB, "
                f"the model's ceiling; Cycles with its denoiser reaches up to {cycles:.2f} dB "
                "here"
            )
        else:
            continue
        lines.append(f"- {r['scene']}, {r['check'].split(',')[0]}: {why}.")
    return ["", "Why the misses:", "", *lines] if lines else []
