"""Shared matplotlib helpers of the bench and study figures.

matplotlib is an optional (dev) dependency: it is imported lazily, with the
non-interactive Agg backend, only when a figure is written, so the numbers
can be computed on a machine without it. Figures are written atomically
(:mod:`cvsss.core.io.atomic`), like every other output.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path
from typing import Any

from ...core.io.atomic import write_bytes

#: One colour per configuration name, shared by the figures of the studies.
COLOURS = {
    "no_cv": "tab:gray",
    "sf": "tab:orange",
    "sf_ema": "tab:brown",
    "emcm": "tab:blue",
    "hat_emcm": "tab:red",
    "gt": "black",
    "as": "tab:gray",
    "as_ocv": "tab:blue",
    "as_ccv": "tab:red",
}


def pyplot() -> Any:
    """``matplotlib.pyplot`` with the Agg backend selected.

    Raises
    ------
    ImportError
        With an installation hint when matplotlib is missing.
    """
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            "matplotlib is needed to write the figures: pip install matplotlib"
        ) from exc
    matplotlib.use("Agg", force=True)
    with warnings.catch_warnings():
        # mathtext's pyparsing calls warn on recent pyparsing; not ours to fix.
        warnings.simplefilter("ignore", DeprecationWarning)
        import matplotlib.pyplot as plt

    return plt


def save(fig: Any, path: str | Path, dpi: int = 120) -> Path:
    """Write ``fig`` to ``path`` atomically (parents created; format from the suffix) and close it."""
    plt = pyplot()
    path = Path(path)
    buffer = io.BytesIO()
    try:
        with warnings.catch_warnings():
            # Log-axis tick labels go through mathtext (see pyplot()).
            warnings.simplefilter("ignore", DeprecationWarning)
            fig.tight_layout()
            fig.savefig(buffer, dpi=dpi, format=path.suffix.lstrip(".") or "png")
    finally:
        plt.close(fig)
    write_bytes(path, buffer.getvalue())
    return path
