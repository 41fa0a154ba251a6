"""The text of a run's progress: what ``cvsss`` and the Blender operators print.

The core reports :class:`core.run.Progress` events; this module turns them into
the one-line messages users read.
"""

from __future__ import annotations

from collections.abc import Callable

from ..core.eval.rows import format_value
from ..core.run import Progress


def format_clock(seconds: float) -> str:
    """``m:ss`` (or ``h:mm:ss``) of a duration in seconds, for progress lines."""
    minutes, sec = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{sec:02d}" if hours else f"{minutes}:{sec:02d}"


def progress_text(event: Progress) -> str:
    """One line for a progress event of a run."""
    if event.kind == "frame":
        result = event.result
        return (
            f"frame {event.index}/{event.total} ({event.frame}) {event.method:>9}: "
            f"spp {result.spp:7.2f}  pass {result.sampling_ms:8.2f} ms  "
            f"psnr {format_value(event.psnr, 2) or '-':>6} dB  "
            f"[elapsed {format_clock(event.elapsed)}, eta {format_clock(event.eta)}]"
        )
    if event.kind == "resumed":
        where = f"after frame {event.frame}" if event.frame is not None else "at the first frame"
        left = event.total - event.index
        return f"{event.method}: resuming {where} ({event.index} done, {left} to go)"
    if event.kind == "warm-up":
        return f"warm-up frame {event.frame} processed (not written)"
    if event.kind == "nothing to do":
        return f"all {event.total} frames were already done; nothing to do"
    raise ValueError(f"unknown progress event {event.kind!r}")


def printer(log: Callable[[str], None] | None) -> Callable[[Progress], None] | None:
    """A receiver of progress events that prints them with ``log`` (None: silent)."""
    if log is None:
        return None
    return lambda event: log(progress_text(event))
