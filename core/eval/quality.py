"""The quality knob: a target PSNR or a mean sample budget mapped to parameters.

Users think in "how good" (a PSNR in dB) or "how expensive" (mean samples per
SSS pixel); the algorithm's knob is σ0², the target variance of the tracked
luminance. This module maps one to the other through a *measured*
calibration: ``cvsss bench`` runs every adaptive method over a sweep of σ0²
on its flashing-light sequence, measures mean PSNR against the reference and
mean spp, and writes the curves to ``quality_calibration.json``. The copy
shipped in ``core/data/`` is regenerated with::

    cvsss bench --out out/bench --write-calibration

Calibration families
--------------------
With the paper's β_min = 8 the cheapest setting of an adaptive method
(σ0² large, every pixel at β_min) already reaches a PSNR floor (≈ 49 dB on
the bench sequence), so a lower target cannot be met by σ0² alone. The
calibration therefore holds *families*: the σ0² sweep at β_min = 8 (the
paper's), then shorter sweeps at β_min = 4 and 2. A target is served by the
first family, in order of decreasing β_min, whose measured range contains it;
β_min is lowered only when the target lies below the floor of every larger
β_min. (Lower β_min is not used more eagerly because pixels that draw one or
two samples underestimate their variance and starve: measured on the bench
sequence, as_ccv at β_min = 1 stops improving beyond 48 dB whatever σ0².)
``fixed`` is calibrated over N instead of σ0².

Inside a family, PSNR and spp are interpolated linearly in log10 of the
swept parameter, after forcing the measured curve to be monotone
(PSNR and spp never increase with σ0²). Targets outside every family's range
are clamped to the nearest end and flagged (``QualityChoice.clamped``).

Scope: PSNR depends on the scene, its lighting and the resolution (a larger
footprint puts less energy in the sampled distant region). The calibration
records the sequence it was measured on; the bench reports how well the
mapping transfers to another resolution.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ..params import SSSParams

#: The calibration shipped with the package.
CALIBRATION_PATH = Path(__file__).resolve().parent.parent / "data" / "quality_calibration.json"

#: Command that regenerates :data:`CALIBRATION_PATH`.
REGENERATE_COMMAND = "cvsss bench --out out/bench --write-calibration"

CALIBRATION_VERSION = 1

_QUALITY_RE = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(db|spp)\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class QualityTarget:
    """What the user asked for.

    Attributes
    ----------
    kind : {"psnr", "spp"}
        ``psnr``: mean luminance PSNR over SSS pixels against the reference,
        dB (display-referred, see core.metrics.psnr); ``spp``: mean distant
        samples per SSS pixel per frame.
    value : float, > 0
    """

    kind: str
    value: float

    def __post_init__(self) -> None:
        if self.kind not in ("psnr", "spp"):
            raise ValueError(f"quality kind must be 'psnr' or 'spp', got {self.kind!r}")
        if not (math.isfinite(self.value) and self.value > 0):
            raise ValueError(f"quality value must be finite and > 0, got {self.value}")

    def __str__(self) -> str:
        return f"{self.value:g} dB" if self.kind == "psnr" else f"{self.value:g} spp"


def parse_quality(text: str) -> QualityTarget:
    """Parse ``"45dB"`` / ``"45 dB"`` (target PSNR) or ``"24spp"`` (mean spp budget).

    >>> parse_quality("45dB")
    QualityTarget(kind='psnr', value=45.0)
    >>> parse_quality("24 spp")
    QualityTarget(kind='spp', value=24.0)
    """
    m = _QUALITY_RE.match(str(text))
    if not m:
        raise ValueError(
            f"quality must be a target PSNR like '45dB' or a mean sample budget like '24spp', "
            f"got {text!r}"
        )
    value = float(m.group(1))
    kind = "psnr" if m.group(2).lower() == "db" else "spp"
    if kind == "psnr" and not 1.0 <= value <= 100.0:
        raise ValueError(f"quality PSNR must be in [1, 100] dB, got {value:g} dB")
    if kind == "spp" and not 1.0 <= value <= 4096.0:
        raise ValueError(f"quality budget must be in [1, 4096] spp, got {value:g} spp")
    return QualityTarget(kind, value)


@dataclass(frozen=True)
class Family:
    """One calibrated sweep of a method.

    Attributes
    ----------
    param : {"target_variance", "fixed_spp"}
        The swept SSSParams field.
    values : (K,) float, swept values, ascending
    psnr_db : (K,) float, mean PSNR measured at each value (dB)
    spp : (K,) float, mean spp measured at each value
    fixed : dict, other SSSParams fields the sweep held (e.g. ``beta_min``)
    """

    param: str
    values: np.ndarray
    psnr_db: np.ndarray
    spp: np.ndarray
    fixed: dict

    @classmethod
    def from_dict(cls, data: dict) -> Family:
        order = np.argsort(np.asarray(data["values"], dtype=np.float64))
        values = np.asarray(data["values"], dtype=np.float64)[order]
        psnr = np.asarray(data["psnr_db"], dtype=np.float64)[order]
        spp = np.asarray(data["spp"], dtype=np.float64)[order]
        if values.size < 1 or psnr.shape != values.shape or spp.shape != values.shape:
            raise ValueError("calibration family needs equal-length values, psnr_db and spp")
        if not (np.all(np.isfinite(values)) and np.all(values > 0)):
            raise ValueError("calibration values must be finite and > 0")
        return cls(str(data["param"]), values, psnr, spp, dict(data.get("fixed", {})))

    @property
    def decreasing(self) -> bool:
        """Quality falls as the parameter grows (σ0²) rather than rises (N)."""
        return self.param == "target_variance"

    def _curves(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, psnr, spp) with x = log10(value) ordered so that quality rises, made monotone."""
        x = np.log10(self.values)
        psnr, spp = self.psnr_db.copy(), self.spp.copy()
        if self.decreasing:
            x, psnr, spp = x[::-1], psnr[::-1], spp[::-1]
        # Measured means carry noise: force monotone non-decreasing along rising quality.
        return (
            x,
            np.maximum.accumulate(np.nan_to_num(psnr, nan=-np.inf)),
            np.maximum.accumulate(spp),
        )

    def invert(self, kind: str, target: float) -> tuple[float, float, float, bool]:
        """``(value, psnr, spp, clamped)`` of the cheapest setting meeting ``target``."""
        x, psnr, spp = self._curves()
        y = psnr if kind == "psnr" else spp
        if kind == "psnr":
            # Cheapest point that reaches the target; clamp at the ends.
            hit = np.flatnonzero(y >= target)
            if hit.size == 0:
                k, t, clamped = len(y) - 1, 0.0, True
            elif hit[0] == 0:
                k, t, clamped = 0, 0.0, y[0] > target + 1e-9
            else:
                k = hit[0]
                t = (target - y[k - 1]) / (y[k] - y[k - 1])
                k, t, clamped = k - 1, t, False
        else:
            # Highest quality that stays within the budget.
            fit = np.flatnonzero(y <= target)
            if fit.size == 0:
                k, t, clamped = 0, 0.0, True
            elif fit[-1] == len(y) - 1:
                k, t, clamped = len(y) - 1, 0.0, y[-1] < target - 1e-9
            else:
                k = fit[-1]
                t = (target - y[k]) / (y[k + 1] - y[k])
                clamped = False
        k1 = min(k + 1, len(x) - 1)
        xv = x[k] + t * (x[k1] - x[k])
        return (
            float(10.0**xv),
            float(psnr[k] + t * (psnr[k1] - psnr[k])),
            float(spp[k] + t * (spp[k1] - spp[k])),
            bool(clamped),
        )

    def reaches(self, kind: str, target: float) -> bool:
        """The family's measured range contains ``target``."""
        _, psnr, spp = self._curves()
        y = psnr if kind == "psnr" else spp
        return bool(y[0] - 1e-9 <= target <= y[-1] + 1e-9)


@dataclass(frozen=True)
class Calibration:
    """Measured quality curves per method (see module docstring)."""

    methods: dict[str, list[Family]]
    source: dict

    @classmethod
    def from_dict(cls, data: dict) -> Calibration:
        if int(data.get("version", 0)) != CALIBRATION_VERSION:
            raise ValueError(
                f"quality calibration version {data.get('version')!r} is not "
                f"{CALIBRATION_VERSION}; regenerate it with `{REGENERATE_COMMAND}`"
            )
        methods = {
            name: [Family.from_dict(f) for f in entry["families"]]
            for name, entry in data["methods"].items()
        }
        source = {k: v for k, v in data.items() if k != "methods"}
        return cls(methods, source)

    def describe(self) -> str:
        """One line naming the sequence the calibration was measured on."""
        s = self.source
        return f"{s.get('scene', '?')} ({s.get('resolution', '?')}, {s.get('frames', '?')} frames)"


@lru_cache(maxsize=4)
def _load_cached(path: str, mtime: float) -> Calibration:
    with open(path, encoding="utf-8") as fh:
        return Calibration.from_dict(json.load(fh))


def load_calibration(path: str | Path | None = None) -> Calibration:
    """Read a calibration file (default: the one shipped in ``core/data``).

    Raises
    ------
    FileNotFoundError, ValueError
        Missing or malformed file; the message names the file and the
        command that regenerates it.
    """
    path = Path(path) if path is not None else CALIBRATION_PATH
    try:
        return _load_cached(str(path), path.stat().st_mtime)
    except FileNotFoundError:
        raise FileNotFoundError(
            f"quality calibration {path} not found; regenerate it with `{REGENERATE_COMMAND}`"
        ) from None
    except (KeyError, TypeError, json.JSONDecodeError) as exc:
        raise ValueError(
            f"quality calibration {path} is malformed ({exc}); "
            f"regenerate it with `{REGENERATE_COMMAND}`"
        ) from None


@dataclass(frozen=True)
class QualityChoice:
    """Parameters picked for a target, with what the calibration predicts.

    Attributes
    ----------
    method : str
    target : QualityTarget
    changes : dict, SSSParams fields to set (``target_variance`` and
        ``beta_min``, or ``fixed_spp``)
    predicted_psnr_db, predicted_spp : float, interpolated from the calibration
    clamped : bool, the target lies outside the calibrated range; the nearest
        end was used
    """

    method: str
    target: QualityTarget
    changes: dict
    predicted_psnr_db: float
    predicted_spp: float
    clamped: bool

    def describe(self) -> str:
        parts = ", ".join(
            f"σ0² = {v:.3g}" if k == "target_variance" else f"{k} = {v}"
            for k, v in self.changes.items()
        )
        text = (
            f"quality {self.target} → {self.method}: {parts} (predicted "
            f"{self.predicted_psnr_db:.1f} dB at {self.predicted_spp:.1f} spp)"
        )
        if self.clamped:
            text += "; the target is outside the calibrated range, the nearest end is used"
        return text


def choose(
    target: QualityTarget | str,
    method: str,
    calibration: Calibration | None = None,
    *,
    beta_min: int | None = None,
) -> QualityChoice:
    """Pick parameters of ``method`` that meet ``target`` on the calibration.

    Parameters
    ----------
    target : QualityTarget or str (``"45dB"``, ``"24spp"``)
    method : str, a calibrated method (``as``, ``as_ocv``, ``as_ccv``, ``fixed``)
    calibration : Calibration, default the shipped one
    beta_min : int, optional
        Restrict to the family with this β_min (the user fixed it).

    Returns
    -------
    QualityChoice

    Raises
    ------
    ValueError
        The method is not calibrated, or ``beta_min`` has no family.
    """
    if isinstance(target, str):
        target = parse_quality(target)
    cal = calibration or load_calibration()
    families = cal.methods.get(method)
    if not families:
        raise ValueError(
            f"quality applies to the calibrated methods {', '.join(cal.methods)}; got {method!r}"
        )
    if beta_min is not None:
        families = [f for f in families if f.fixed.get("beta_min") == beta_min]
        if not families:
            raise ValueError(f"no quality calibration of {method} at beta_min={beta_min}")
    # Preferred order: the paper's β_min first (larger β_min is more robust).
    ordered = sorted(families, key=lambda f: -int(f.fixed.get("beta_min", 0)))
    pick = next((f for f in ordered if f.reaches(target.kind, target.value)), None)
    if pick is None:
        # Outside every range: the family whose range ends closest to the target.
        def gap(f: Family) -> float:
            _, psnr, spp = f._curves()
            y = psnr if target.kind == "psnr" else spp
            return min(abs(y[0] - target.value), abs(y[-1] - target.value))

        pick = min(ordered, key=gap)
    value, psnr, spp, clamped = pick.invert(target.kind, target.value)
    if pick.param == "fixed_spp":
        n = max(1, round(value))
        changes = {"fixed_spp": int(n)}
    else:
        changes = {"target_variance": float(f"{value:.4g}")}
        changes.update({k: v for k, v in pick.fixed.items() if k in SSSParams.field_names()})
    return QualityChoice(method, target, changes, psnr, spp, clamped)


def apply(
    params: SSSParams,
    target: QualityTarget | str,
    method: str,
    calibration: Calibration | None = None,
) -> tuple[SSSParams, QualityChoice]:
    """``params`` with the fields :func:`choose` picked for ``method`` replaced."""
    choice = choose(target, method, calibration)
    return params.replace(**choice.changes), choice


def calibration_dict(
    curves: dict[str, list[dict[str, Any]]], source: dict[str, Any]
) -> dict[str, Any]:
    """Assemble a calibration file body from measured curves.

    Parameters
    ----------
    curves : ``{method: [{"param", "values", "psnr_db", "spp", "fixed"}, …]}``
    source : metadata: ``scene``, ``resolution``, ``frames``, ``params``, …
    """
    return {
        "version": CALIBRATION_VERSION,
        "command": REGENERATE_COMMAND,
        **source,
        "methods": {m: {"families": fams} for m, fams in curves.items()},
    }
