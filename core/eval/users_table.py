"""What the user had against what they get: the rows of ``cvsss compare``, the targets, the table.

A *row* is one way of rendering a scene's frames, measured against Cycles'
ground truth (:mod:`.users_frame`): the scene's engine as set (``plain``),
Apply on Render's defaults on the same engine and settings
(``apply_on_render``) or the same engine without subsurface (``off``, the
floor the effect is measured from). Its keys:

``kind``            ``"plain"``, ``"apply_on_render"`` or ``"off"``
``engine``          ``"CYCLES"`` or ``"EEVEE"``
``samples``         Cycles' samples per pixel, or EEVEE's render samples
``denoise``         bool, Cycles' own denoiser on
``variant``         the subsurface method asked for: ``"material"`` (as the
                    materials set it), ``"RANDOM_WALK"`` or ``"BURLEY"``
``method``          the method the materials then use (``"mixed"`` when they differ)
``label``           what the table calls it
``frames``          the frames measured
``figures``         frame (str) -> :class:`.users_frame.FrameFigures` as a dict
``mean``            :func:`.users_frame.mean_figures` of them
``seconds_per_frame``         wall seconds of the render over the frames delivered,
                              everything the user waits for included
``setup_seconds``             of which before the first frame began rendering
                              (Apply on Render: its set-up and warm-up frames)
``steady_seconds_per_frame``  the rest over the frames delivered
``objects``         object name -> :func:`.users_frame.object_errors`' sums over the
                    frames (``pixels``, ``display_sse``, ``effect_sse``; ``""``: no object)
``cycles_renders``  (Apply on Render) the objects whose subsurface Cycles renders whole

:func:`check_targets` holds the pairs (``plain``, ``apply_on_render``) of one
setting against issue 44's targets and says, for each missed one, what was
measured beside it; :func:`format_table` and :func:`format_targets` write
Markdown.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

from .users_frame import mse_db

KINDS = ("plain", "apply_on_render", "off")

#: Figures of the table: (key of ``mean``, column title).
COLUMNS = (
    ("psnr_whole_db", "whole (dB)"),
    ("psnr_subsurface_db", "subsurface (dB)"),
    ("effect_db", "effect (dB)"),
)

#: Apply on Render's seconds per frame may be at most this many times plain's.
TIME_RATIO = 1.25


def _target(name: str, key: str, offset: float) -> dict:
    return {"name": name, "key": key, "offset": offset}


#: Issue 44's targets per (engine, subsurface method): Apply on Render's figure ``key``
#: must reach plain's + ``offset`` dB; ``"time"`` is the seconds-per-frame ratio.
TARGETS = {
    ("CYCLES", "RANDOM_WALK"): (
        _target("whole frame >= plain - 0.5 dB", "psnr_whole_db", -0.5),
        _target("subsurface pixels >= plain - 0.5 dB", "psnr_subsurface_db", -0.5),
        _target(f"time per frame <= {TIME_RATIO} x plain", "time", TIME_RATIO),
    ),
    ("CYCLES", "BURLEY"): (
        _target("subsurface pixels >= plain + 1 dB", "psnr_subsurface_db", 1.0),
        _target("whole frame >= plain", "psnr_whole_db", 0.0),
        _target(f"time per frame <= {TIME_RATIO} x plain", "time", TIME_RATIO),
    ),
    ("EEVEE", None): (
        _target("subsurface effect >= EEVEE's own + 1 dB", "effect_db", 1.0),
        _target("whole frame >= EEVEE's own - 0.5 dB", "psnr_whole_db", -0.5),
    ),
}


def setting(row: dict) -> tuple:
    """What makes two rows comparable: engine, samples, denoiser and method variant."""
    return (row["engine"], row["samples"], bool(row["denoise"]), row["variant"])


def setting_label(row: dict) -> str:
    """``Cycles 16 spp + denoiser, Random Walk`` and the like."""
    if row["engine"] == "CYCLES":
        text = f"Cycles {row['samples']} spp" + (" + denoiser" if row["denoise"] else "")
    else:
        text = f"EEVEE {row['samples']} samples"
    method = {"RANDOM_WALK": "Random Walk", "BURLEY": "Christensen-Burley"}.get(
        row["method"], row["method"]
    )
    asked = "" if row["variant"] != "material" else " (the materials' own)"
    return f"{text}, {method}{asked}"


def _fmt(value, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:.{digits}f}"


def _targets_of(row: dict) -> tuple[dict, ...]:
    if row["engine"] == "EEVEE":
        return TARGETS[("EEVEE", None)]
    if not row["denoise"]:
        return ()  # the Cycles targets are for Cycles with its denoiser
    return TARGETS.get(("CYCLES", row["method"]), ())


def pairs(rows: Iterable[dict]) -> list[tuple[dict, dict, dict | None]]:
    """(plain, apply_on_render, off or None) of every setting that has both, in row order."""
    rows = list(rows)
    out = []
    for plain in (r for r in rows if r["kind"] == "plain"):
        ours = [r for r in rows if r["kind"] == "apply_on_render" and setting(r) == setting(plain)]
        if not ours:
            continue
        off = [r for r in rows if r["kind"] == "off" and setting(r) == setting(plain)]
        out.append((plain, ours[0], off[0] if off else None))
    return out


def check_targets(rows: Iterable[dict]) -> list[dict]:
    """Each target of :data:`TARGETS` that applies to a pair of rows, met or not.

    Returns
    -------
    list of dict: ``setting`` (label), ``target`` (its name), ``plain`` and
    ``ours`` (the figures compared: dB, or seconds per frame), ``required``
    (the bound ours must reach), ``met`` (bool, or None when a figure is
    missing) and ``why``: for a missed target, what was measured beside it.
    """
    out = []
    for plain, ours, off in pairs(rows):
        for target in _targets_of(plain):
            if target["key"] == "time":
                a, b = plain["seconds_per_frame"], ours["seconds_per_frame"]
                required = a * target["offset"]
                met = None if not (math.isfinite(a) and math.isfinite(b)) else b <= required
            else:
                a = plain["mean"].get(target["key"], float("nan"))
                b = ours["mean"].get(target["key"], float("nan"))
                required = a + target["offset"]
                met = None if not (math.isfinite(a) and math.isfinite(b)) else b >= required
            entry = {
                "setting": setting_label(plain),
                "target": target["name"],
                "plain": a,
                "ours": b,
                "required": required,
                "met": met,
                "why": [],
            }
            if met is False:
                entry["why"] = why_missed(target["key"], plain, ours, off)
            out.append(entry)
    return out


def why_missed(key: str, plain: dict, ours: dict, off: dict | None) -> list[str]:
    """What was measured beside a missed target (figures only; the reading is the reader's)."""
    if key == "time":
        frames = len(ours["frames"])
        return [
            f"before the first of {frames} frame(s): Apply on Render "
            f"{_fmt(ours['setup_seconds'])} s (its set-up and warm-up frames), plain "
            f"{_fmt(plain['setup_seconds'])} s",
            f"after it, per frame: Apply on Render {_fmt(ours['steady_seconds_per_frame'])} s, "
            f"plain {_fmt(plain['steady_seconds_per_frame'])} s",
        ]
    p, o = plain["mean"], ours["mean"]
    lines = [
        f"outside the subsurface pixels ({_fmt(100 * (1 - o.get('subsurface_share', 0)), 1)} % "
        f"of the frame): Apply on Render {_fmt(o.get('psnr_rest_db'))} dB, plain "
        f"{_fmt(p.get('psnr_rest_db'))} dB",
        f"on the subsurface pixels: Apply on Render {_fmt(o.get('psnr_subsurface_db'))} dB, "
        f"plain {_fmt(p.get('psnr_subsurface_db'))} dB",
        f"the subsurface effect: Apply on Render {_fmt(o.get('effect_db'))} dB, plain "
        f"{_fmt(p.get('effect_db'))} dB",
    ]
    if off is not None:
        lines.append(
            f"the same engine without subsurface: {_fmt(off['mean'].get('psnr_subsurface_db'))} "
            f"dB on the subsurface pixels, {_fmt(off['mean'].get('psnr_whole_db'))} dB whole"
        )
    return lines + by_object(key, plain, ours)


#: At most this many objects in :func:`by_object`'s lines (those with most of plain's error).
OBJECT_LINES = 6

#: A ``why`` line that starts with this is a sub-item of the line before it.
SUB = "\t"


def by_object(key: str, plain: dict, ours: dict) -> list[str]:
    """Which objects a missed figure's gain or loss comes from: per object, on its
    subsurface pixels over the frames, plain's and Apply on Render's PSNR (the
    effect's for ``effect_db``, the frame's otherwise) and its share of plain's squared
    error; the objects with most of that error first. Empty without the rows'
    ``objects``."""
    a, b = plain.get("objects") or {}, ours.get("objects") or {}
    sse = "effect_sse" if key == "effect_db" else "display_sse"
    total = sum(v[sse] for v in a.values() if math.isfinite(v[sse]))
    if not a or not b or total <= 0:
        return []
    cycles = set(ours.get("cycles_renders") or ())
    what = "the subsurface effect" if key == "effect_db" else "the frame"
    lines = [f"by object, {what} on its subsurface pixels (plain → Apply on Render):"]
    ranked = sorted(a, key=lambda name: -a[name][sse] if math.isfinite(a[name][sse]) else 0)
    for name in ranked[:OBJECT_LINES]:
        if name not in b:
            continue
        n = a[name]["pixels"]
        share = a[name][sse] / total
        whole = " (Cycles renders its subsurface)" if name in cycles else ""
        lines.append(
            f"{SUB}{name or '(no object)'}{whole}: {_fmt(_db(a[name][sse], n))} → "
            f"{_fmt(_db(b[name][sse], n))} dB on {n} pixels ({_fmt(100 * share, 1)} % of plain's "
            f"squared error)"
        )
    return lines


def _db(sse: float, pixels: int) -> float:
    """PSNR of a squared error summed over ``pixels`` (:func:`.users_frame.mse_db`)."""
    return mse_db(sse / pixels) if pixels > 0 else float("nan")


def row_label(row: dict) -> str:
    """What the table's first column calls a row."""
    if row["kind"] == "apply_on_render":
        return f"Apply on Render ({row.get('post_method', 'defaults')})"
    if row["kind"] == "off":
        return "without subsurface"
    return "plain"


def format_table(rows: Sequence[dict], scene: str | None = None) -> str:
    """Markdown: one line per row, grouped by setting (what you had, then what you get)."""
    head = "| setting | what | " + " | ".join(t for _, t in COLUMNS) + " | s / frame (steady) |"
    lines = [head, "| --- | --- |" + " ---: |" * (len(COLUMNS) + 1)]
    if scene is not None:
        lines[0] = "| scene " + lines[0]
        lines[1] = "| --- " + lines[1]
    order = {k: i for i, k in enumerate(KINDS)}
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault(setting(row), []).append(row)
    for group in groups.values():
        for row in sorted(group, key=lambda r: order[r["kind"]]):
            figures = " | ".join(_fmt(row["mean"].get(key)) for key, _ in COLUMNS)
            seconds = f"{_fmt(row['seconds_per_frame'])} ({_fmt(row['steady_seconds_per_frame'])})"
            cells = f"| {setting_label(row)} | {row_label(row)} | {figures} | {seconds} |"
            lines.append((f"| {scene} " if scene is not None else "") + cells)
    return "\n".join(lines)


def format_targets(checks: Sequence[dict]) -> str:
    """Markdown list: each target met or missed, with the figures and, when missed, why."""
    lines = []
    for c in checks:
        mark = {True: "met", False: "MISSED", None: "not measured"}[c["met"]]
        unit = " s" if "time" in c["target"] else " dB"
        lines.append(
            f"- {c['setting']}: {c['target']}: {mark} (Apply on Render {_fmt(c['ours'])}{unit}, "
            f"plain {_fmt(c['plain'])}{unit}, bound {_fmt(c['required'])}{unit})"
        )
        lines += [
            f"    - {why[len(SUB) :]}" if why.startswith(SUB) else f"  - {why}" for why in c["why"]
        ]
    return "\n".join(lines)
