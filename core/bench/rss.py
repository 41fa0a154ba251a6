"""Section ``rss``: peak memory per method and history precision (measured by the front-end)."""

from __future__ import annotations

from ..methods import METHODS
from .config import BenchConfig, Log, MeasureRss, progress, size_key


# -- memory ------------------------------------------------------------------------
def rss_specs(cfg: BenchConfig) -> tuple[list[dict], dict | None]:
    """The memory section's configurations, and a two-frame check of one of them.

    Returns
    -------
    specs : [{"size": [w, h], "method", "precision", "frames": 1, "scene", "seed"}],
        per size, method (plus ``separable`` with its default kernel when
        ``cfg.rss_separable``) and history precision (both for adaptive methods)
    check : the first adaptive spec with ``frames = 2``, or None. One frame
        suffices: the first frame allocates every buffer (the history, its
        reprojected copy, sample batches bounded by chunk_samples); the check
        measures a second frame to show it.
    """
    methods = list(cfg.rss_methods)
    if cfg.rss_separable and "separable" not in methods:
        methods.append("separable")
    specs = [
        {
            "size": list(size),
            "method": method,
            "precision": prec,
            "frames": 1,
            "scene": cfg.scene,
            "seed": cfg.seed,
        }
        for size in cfg.rss_sizes
        for method in methods
        for prec in (("float32", "float16") if METHODS[method].adaptive else ("float32",))
    ]
    adaptive = next((s for s in specs if METHODS[s["method"]].adaptive), None)
    return specs, None if adaptive is None else dict(adaptive, frames=2)


def section_rss(
    cfg: BenchConfig, measure: MeasureRss, log: Log = None, start: float | None = None
) -> dict:
    """Peak RSS per size, method and history precision.

    Parameters
    ----------
    cfg : BenchConfig
    measure : callable [spec] -> [result], the memory of one fresh process per
        spec of :func:`rss_specs` (and the check), in order; a result holds
        ``peak_rss_mb`` (and whatever else the measurement reports) or ``error``
    """
    specs, check = rss_specs(cfg)
    results = measure([*specs, check] if check else specs)
    table: dict[str, dict] = {}
    rows = []
    for spec, res in zip(specs, results):
        row = {
            "size": size_key(spec["size"]),
            "method": spec["method"],
            "precision": spec["precision"],
            **res,
        }
        rows.append(row)
        table.setdefault(row["size"], {}).setdefault(row["method"], {})[spec["precision"]] = (
            res.get("peak_rss_mb")
        )
        progress(
            log,
            start,
            f"rss {row['size']} {row['method']:>6} {row['precision']}: "
            f"{res.get('peak_rss_mb', float('nan')):8.1f} MB "
            f"{res.get('error', '')}",
        )
    out = {**table, "rows": rows, "frames": 1}
    if check:
        one = next(r for r, s in zip(rows, specs) if s == dict(check, frames=1))
        out["second_frame_check"] = {
            "size": size_key(check["size"]),
            "method": check["method"],
            "precision": check["precision"],
            "one_frame_mb": one.get("peak_rss_mb"),
            "two_frames_mb": results[-1].get("peak_rss_mb"),
        }
    return out
