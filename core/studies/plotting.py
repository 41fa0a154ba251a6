"""Shared matplotlib helpers of the 1D studies.

matplotlib is an optional (dev) dependency: it is imported lazily, with the
non-interactive Agg backend, only when a figure is written, so the studies'
numbers can be computed on a machine without it.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

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
            "matplotlib is needed to write the study figures: pip install matplotlib"
        ) from exc
    matplotlib.use("Agg", force=True)
    with warnings.catch_warnings():
        # mathtext's pyparsing calls warn on recent pyparsing; not ours to fix.
        warnings.simplefilter("ignore", DeprecationWarning)
        import matplotlib.pyplot as plt

    return plt


def save(fig: Any, path: str | Path, dpi: int = 120) -> Path:
    """Write ``fig`` to ``path`` (parents created) and close it."""
    plt = pyplot()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        # Log-axis tick labels go through mathtext (see pyplot()).
        warnings.simplefilter("ignore", DeprecationWarning)
        fig.tight_layout()
        fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
