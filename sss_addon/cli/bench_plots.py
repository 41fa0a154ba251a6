"""The figures of ``cvsss bench``: the speed/accuracy trade (pareto.png,
pareto_backends.png), quality against the σ0² knob (quality.png) and time
against image size and subsurface coverage (scaling.png), drawn from a bench
result (the dict written to bench.json)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...core.bench.config import ADAPTIVE
from .plots import pyplot, save

_COLOURS = {
    "fixed": "tab:gray",
    "as": "tab:green",
    "as_ocv": "tab:blue",
    "as_ccv": "tab:red",
    "separable": "tab:purple",
}


def write_plots(result: dict, out: Path) -> list[Path]:
    """pareto.png and quality.png (with a Pareto section) and scaling.png from a bench result."""
    plt = pyplot()
    written = []
    par = result.get("pareto")
    if par:
        written.append(_plot_pareto(plt, par, out / "pareto.png"))
        if par.get("by_backend"):
            written.append(_plot_pareto_backends(plt, par, out / "pareto_backends.png"))
        written.append(_plot_quality(plt, par, out / "quality.png"))
    written.append(_plot_scaling(plt, result, out / "scaling.png"))
    return written


def _plot_pareto(plt: Any, par: dict, path: Path) -> Path:
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    pts = par["points"]
    for ax, xkey, xlabel in (
        (axes[0], "sampling_ms", "mean sampling time per frame (ms)"),
        (axes[1], "spp", "mean samples per SSS pixel"),
    ):
        for method in dict.fromkeys(p["method"] for p in pts):
            if xkey == "spp" and method == "separable":
                continue  # reads per pixel, not samples
            for fam, marker, fill in (("sweep", "o", True), ("calibration", "s", False)):
                ps = [p for p in pts if p["method"] == method and p["family"] == fam]
                if not ps:
                    continue
                c = _COLOURS.get(method, "k")
                ax.scatter(
                    [p[xkey] for p in ps],
                    [p["psnr_db"] for p in ps],
                    marker=marker,
                    facecolors=c if fill else "none",
                    edgecolors=c,
                    s=36,
                    label=method if fam == "sweep" else f"{method} (other β_min / σ0²)",
                )
                if fam == "sweep" and method != "separable":
                    ps = sorted(ps, key=lambda p: p["value"])
                    ax.plot(
                        [p[xkey] for p in ps],
                        [p["psnr_db"] for p in ps],
                        color=c,
                        lw=0.8,
                        alpha=0.6,
                    )
        if xkey == "sampling_ms":
            front = sorted((p for p in pts if p["front"]), key=lambda p: p["sampling_ms"])
            ax.step(
                [p["sampling_ms"] for p in front],
                [p["psnr_db"] for p in front],
                where="post",
                color="k",
                lw=2,
                alpha=0.5,
                label="Pareto front",
            )
            for p in front:
                if p["family"] != "sweep":
                    continue  # calibration-only points: markers without labels
                ax.annotate(
                    p["label"].replace("σ0²=", ""),
                    (p["sampling_ms"], p["psnr_db"]),
                    fontsize=6,
                    xytext=(3, -8),
                    textcoords="offset points",
                )
        ax.set_xscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("mean PSNR vs reference (dB)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7, loc="lower right")
    axes[0].set_title(f"{par['scene']} {par['size']}, {par['frames']} frames")
    axes[1].set_title("same points against mean spp")
    return save(fig, path)


def _plot_pareto_backends(plt: Any, par: dict, path: Path) -> Path:
    """PSNR against sampling time of the Monte Carlo sweep, one panel per sampling backend."""
    backends = list(par["by_backend"])
    fig, axes = plt.subplots(1, len(backends), figsize=(6 * len(backends), 4.8), squeeze=False)
    for ax, b in zip(axes[0], backends):
        pts = [p for p in par["by_backend"][b] if p["method"] != "separable"]
        for method in dict.fromkeys(p["method"] for p in pts):
            mine = sorted((p for p in pts if p["method"] == method), key=lambda p: p["sampling_ms"])
            ax.plot(
                [p["sampling_ms"] for p in mine],
                [p["psnr_db"] for p in mine],
                "o-",
                color=_COLOURS.get(method),
                label=method,
            )
        front = sorted((p for p in pts if p["front"]), key=lambda p: p["sampling_ms"])
        ax.plot([p["sampling_ms"] for p in front], [p["psnr_db"] for p in front], "k--", lw=1)
        ax.set_xscale("log")
        ax.set_xlabel("sampling pass (ms)")
        ax.set_ylabel("PSNR vs 1024 spp (dB)")
        ax.set_title(f"{b}{' (default)' if b == par.get('backend_default') else ''}, {par['size']}")
        ax.legend(fontsize=8)
    return save(fig, path)


def _plot_quality(plt: Any, par: dict, path: Path) -> Path:
    cal = par["calibration"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for method in ADAPTIVE:
        for fam in cal["methods"].get(method, {}).get("families", []):
            bm = fam["fixed"].get("beta_min")
            style = {8: "-", 4: "--", 2: ":"}.get(bm, "-.")
            kw = {"color": _COLOURS[method], "ls": style, "marker": "o", "ms": 3}
            axes[0].plot(fam["values"], fam["psnr_db"], label=f"{method} β_min={bm}", **kw)
            axes[1].plot(fam["values"], fam["spp"], **kw)
    q = par["quality_checks"]
    for key, ax in (("psnr", axes[0]), ("spp", axes[1])):
        c = q.get(key)
        if c and "target_variance" in c["choice"]:
            y = c["measured_psnr_db"] if key == "psnr" else c["measured_spp"]
            ax.scatter(
                [c["choice"]["target_variance"]],
                [y],
                marker="*",
                s=160,
                color="k",
                zorder=5,
                label=f"asked {c['target']:g} {'dB' if key == 'psnr' else 'spp'}"
                f": measured {y:.1f}",
            )
            ax.axhline(c["target"], color="k", lw=0.6, ls="--")
    for ax, ylab in ((axes[0], "mean PSNR (dB)"), (axes[1], "mean spp")):
        ax.set_xscale("log")
        ax.set_xlabel("σ0² (target variance of tracked luminance)")
        ax.set_ylabel(ylab)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_title(f"quality knob calibration ({cal['resolution']})")
    return save(fig, path)


def _time_panel(
    ax: Any, x: list[float], rows: list[dict], keys: tuple[str, str], suffix: str = ""
) -> None:
    """Frame total and sampling pass (``keys``) of scaling rows against ``x``."""
    ax.plot(x, [r[keys[0]] for r in rows], "o-", label=f"frame total{suffix}")
    ax.plot(x, [r[keys[1]] for r in rows], "s-", label=f"sampling pass{suffix}")


def _plot_scaling(plt: Any, result: dict, path: Path) -> Path:
    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    fit = result.get("samples_time_r2")
    if fit:
        ax = axes[0, 0]
        for lab in dict.fromkeys(p[2] for p in fit["points"]):
            ps = [p for p in fit["points"] if p[2] == lab]
            ax.scatter([p[0] / 1e6 for p in ps], [p[1] for p in ps], s=14, label=lab)
        xs = np.linspace(0, max(p[0] for p in fit["points"]), 10)
        ax.plot(xs / 1e6, fit["intercept_ms"] + fit["slope_ns_per_sample"] * 1e-6 * xs, "k--", lw=1)
        ax.set(
            xlabel="samples per frame (millions)",
            ylabel="sampling pass (ms)",
            title=f"time vs samples {fit['size']}: R² = {fit['value']:.4f}",
        )
        ax.legend(fontsize=6)
    cost = result.get("cost")
    if cost:
        ax = axes[0, 1]
        sizes = list(cost["sizes"])
        width = 0.8 / (len(sizes) * 2)
        for j, size in enumerate(sizes):
            rows = cost["sizes"][size]
            xs = np.arange(len(rows))
            ax.bar(
                xs + (2 * j) * width,
                [r["ns_per_sample"] for r in rows.values()],
                width,
                label=f"sampling step {size}",
            )
            ax.bar(
                xs + (2 * j + 1) * width,
                [r["gather_ns_per_sample"] for r in rows.values()],
                width,
                label=f"np.take gather {size}",
                hatch="//",
            )
            ax.set_xticks(xs + width * (len(sizes) - 0.5), list(rows))
        ax.set(ylabel="ns per sample", title="cost per sample vs the gather roofline")
        ax.set_yscale("log")
        ax.legend(fontsize=6)
        bd = {
            k: v
            for k, v in cost.get("breakdown", {}).items()
            if isinstance(v, float) and k != "samples"
        }
        if bd:
            ax = axes[0, 2]
            ax.barh(list(bd), list(bd.values()), color="tab:gray")
            ax.set(xlabel="ns per sample", title=f"building blocks ({cost['breakdown']['size']})")
    cov = result.get("coverage_scaling")
    if cov:
        ax = axes[1, 0]
        rows = cov["rows"]
        _time_panel(ax, [r["sss_pixels"] / 1e3 for r in rows], rows, ("total_ms", "sampling_ms"))
        if "eps_u" in cov:
            e = cov["eps_u"]
            ax.plot(
                [e["default"]["distant_pixels"] / 1e3, e["raised"]["distant_pixels"] / 1e3],
                [e["default"]["sampling_ms"], e["raised"]["sampling_ms"]],
                "k*--",
                ms=10,
                label=f"scene, ε_u {e['default_eps_u']:g} → {e['eps_u']:.2f} "
                "(x = pixels above ε_u)",
            )
        ax.set(
            xlabel="SSS pixels (thousands)",
            ylabel="ms per frame",
            title=f"coverage 10/50/100 % ({cov['size']}, {cov['method']})",
        )
        ax.legend(fontsize=7)
    res = result.get("resolution_scaling")
    if res:
        ax = axes[1, 1]
        rows = res["rows"]
        _time_panel(
            ax,
            [r["pixels"] / 1e6 for r in rows],
            rows,
            ("ns_per_pixel", "pass_ns_per_pixel"),
            " / pixel",
        )
        ax.set_xscale("log")
        ax.set(
            xlabel="megapixels",
            ylabel="ns per pixel",
            ylim=(0, None),
            title=f"resolution scaling ({res['method']})",
        )
        ax.legend(fontsize=7)
    rss = result.get("peak_rss_mb")
    if rss:
        ax = axes[1, 2]
        rows = [r for r in rss["rows"] if r.get("peak_rss_mb") is not None]
        labels = [f"{r['method']} {r['precision'][5:]}\n{r['size']}" for r in rows]
        ax.barh(range(len(rows)), [r["peak_rss_mb"] for r in rows], color="tab:blue")
        ax.set_yticks(range(len(rows)), labels, fontsize=6)
        ax.axvline(4096, color="r", ls="--", lw=1, label="4 GB")
        ax.set(xlabel="peak RSS (MB)", title="peak memory per configuration (1 frame)")
        ax.legend(fontsize=7)
    return save(fig, path)
