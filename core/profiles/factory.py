"""Build a frame's profile from its materials: Burley, dipole or artist-friendly per slot.

Each :class:`~cvsss.core.frame.MaterialSpec` names its profile
(``spec.profile``) and may carry options (``spec.options``, JSON):

``preset``
    A measured material of :mod:`~cvsss.core.profiles.presets` (any profile).
``mm_per_unit``, ``scale`` (or ``preset_scale``, as the add-on writes it)
    Millimetres per scene unit (default 1000: metres) and an artist scale
    (default 1) that convert a preset's millimetres to scene units
    (``unit = scale / mm_per_unit``).

and per profile:

``burley``
    ``d`` is ``spec.d`` (scene units), or the preset's derived Burley shape
    ``ℓ/s(A_tot)`` when a preset is given. A material whose subsurface method
    (``spec.method``) is RANDOM_WALK or RANDOM_WALK_SKIN, without a preset,
    takes the fitted model's shape instead (:func:`.random_walk.shape`) from
    the options ``base_color`` (required), ``subsurface_radius`` and
    ``subsurface_scale`` (default: ``4π·d`` and 1, the same product),
    ``subsurface_ior`` (default 1.4) and ``subsurface_anisotropy`` (default 0);
    its energy per slot is the profile's ``energy``
    (:class:`.energy.SlotEnergy`), which core.energy applies per pixel.
``dipole``
    ``preset``, or explicit ``sigma_a``, ``sigma_s`` (3 values each, mm⁻¹) and
    ``eta``; ``single_scattering`` (default true) selects ``R_{d,ss+ms}``.
``artist``
    Explicit ``strength``, ``near``, ``far``, ``weight`` (3 values each; near
    and far standard deviations in scene units), or derived
    (:func:`~cvsss.core.profiles.artist.from_radial`) from the preset's
    multiple-scattering dipole ``R_{d,ms}`` or, without a preset, from the
    Burley profile of ``spec.d``; an explicit ``strength`` overrides the
    derived one.

A :class:`ProfileChoice` (the command line's ``--profile``/``--material``)
rewrites the materials before the profile is built. When all slots use one
profile kind the result is that profile; otherwise a :class:`MixedProfile`
dispatches each sample to the profile of its slot.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..frame import compact_materials
from ..params import ParameterError, param, validate
from . import presets, random_walk
from .artist import ArtistProfile, from_radial
from .base import Profile, Region
from .burley import CYCLES_TRUNCATE, BurleyProfile
from .dipole import MM_PER_METRE, DipoleProfile
from .energy import SlotEnergy
from .radial import RadialModel, radial_model

PROFILE_NAMES = ("burley", "dipole", "artist")


class ProfileError(ParameterError):
    """A material's profile cannot be built (unknown name, bad options, no parameters)."""


@dataclass(frozen=True)
class ProfileChoice:
    """A global profile / measured-material choice applied to every SSS material slot.

    ``slot_materials`` pairs Material Index values with presets (they override
    ``material``); ``parse_material`` reads the command line's ``--material``.
    """

    profile: str | None = param(
        None,
        label="Profile",
        help="Diffusion profile of every SSS material (default: each material's own, Burley "
        "from its Principled BSDF)",
        choices=PROFILE_NAMES,
    )
    material: str | None = param(
        None,
        help="Measured material for every SSS material, or per Material Index (1=skin1,"
        "2=marble): " + ", ".join(presets.names()),
        flag="",  # --material is parsed by the command line (SLOT=PRESET pairs)
        ui=False,  # in Blender: each material's Subsurface (cvsss) preset
    )
    slot_materials: tuple[tuple[int, str], ...] = ()
    mm_per_unit: float = param(
        MM_PER_METRE,
        help="Millimetres per scene unit for measured materials (1000: metres)",
        unit="mm",
        lo=0.0,
        lo_open=True,
        ui=False,  # in Blender: from the scene's unit scale
    )
    scale: float = param(
        1.0,
        help="Artist scale of the measured materials' scattering distances (1: real size)",
        lo=0.0,
        lo_open=True,
        flag="preset-scale",
        ui=False,  # in Blender: each material's Preset Scale
    )

    def __post_init__(self) -> None:
        validate(self)
        if self.material is not None:
            object.__setattr__(self, "material", presets.get(self.material).name)
        pairs = []
        for slot, name in self.slot_materials:
            if isinstance(slot, bool) or not isinstance(slot, int) or slot < 1:
                raise ValueError(f"material slot must be an integer >= 1, got {slot!r}")
            pairs.append((slot, presets.get(name).name))
        object.__setattr__(self, "slot_materials", tuple(pairs))
        presets.unit_factor(self.mm_per_unit, self.scale)

    @classmethod
    def parse_material(cls, text: str) -> tuple[str | None, tuple[tuple[int, str], ...]]:
        """``"skin1"`` → (skin1, ()); ``"1=skin1,2=marble"`` → (None, ((1, skin1), (2, marble)))."""
        items = [t.strip() for t in str(text).split(",") if t.strip()]
        if not items:
            raise ValueError("material must be a preset name or SLOT=PRESET pairs, got ''")
        if len(items) == 1 and "=" not in items[0]:
            return presets.get(items[0]).name, ()
        pairs = []
        for item in items:
            slot, sep, name = item.partition("=")
            try:
                if not sep:
                    raise ValueError
                number = int(slot)
            except ValueError:
                raise ValueError(
                    f"material must be a preset name or SLOT=PRESET pairs, got {text!r}"
                ) from None
            if any(number == seen for seen, _ in pairs):
                raise ValueError(f"material: slot {number} is given twice in {text!r}")
            pairs.append((number, presets.get(name.strip()).name))
        return None, tuple(pairs)

    @property
    def is_default(self) -> bool:
        return self.profile is None and self.material is None and not self.slot_materials

    def to_dict(self) -> dict:
        """JSON-ready form (run signatures)."""
        return {
            "profile": self.profile,
            "material": self.material,
            "slot_materials": [list(p) for p in self.slot_materials],
            "mm_per_unit": self.mm_per_unit,
            "scale": self.scale,
        }

    def apply(self, materials: Mapping[int, object]) -> dict[int, object]:
        """Materials (slot → MaterialSpec) with this choice applied."""
        by_slot = dict(self.slot_materials)
        unknown = sorted(set(by_slot) - set(materials))
        if unknown:
            raise ProfileError(
                f"material: slot {unknown[0]} is not a material of the passes "
                f"(their slots: {', '.join(str(s) for s in sorted(materials)) or 'none'})"
            )
        out = {}
        for slot, spec in materials.items():
            options = dict(spec.options)
            preset = by_slot.get(slot, self.material)
            if preset is not None:
                options.update(preset=preset, mm_per_unit=self.mm_per_unit, scale=self.scale)
            out[slot] = dataclasses.replace(
                spec, profile=self.profile or spec.profile, options=options
            )
        return out


# -- per-kind construction --------------------------------------------------------------
def _unit(spec) -> float:
    o = spec.options
    try:
        scale = o.get("scale", o.get("preset_scale", 1.0))  # the add-on writes preset_scale
        return presets.unit_factor(o.get("mm_per_unit", MM_PER_METRE), scale)
    except ValueError as exc:
        raise ProfileError(f"material {spec.name!r} (slot {spec.slot}): {exc}") from None


def _triple(spec, key: str) -> np.ndarray:
    value = spec.options[key]
    try:
        a = np.asarray(value, dtype=np.float64).reshape(-1)
        if a.size == 1:
            a = np.repeat(a, 3)
        if a.size != 3 or not np.all(np.isfinite(a)):
            raise ValueError
    except (TypeError, ValueError):
        raise ProfileError(
            f"material {spec.name!r} (slot {spec.slot}): option {key!r} must be "
            f"3 finite numbers, got {value!r}"
        ) from None
    return a


def _preset(spec):
    name = spec.options.get("preset")
    if name is None:
        return None
    try:
        return presets.get(name)
    except ValueError as exc:
        raise ProfileError(f"material {spec.name!r} (slot {spec.slot}): {exc}") from None


def _burley_d(spec) -> np.ndarray:
    p = _preset(spec)
    return np.asarray(spec.d, dtype=np.float64) if p is None else p.burley_d_mm() * _unit(spec)


def _number(spec, key: str, default: float) -> float:
    value = spec.options.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise ProfileError(
            f"material {spec.name!r} (slot {spec.slot}): option {key!r} must be a finite "
            f"number, got {value!r}"
        )
    return float(value)


def _random_walk(spec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """(d, albedo, ℓ, e), each (3,), of a random-walk material, or None: a BURLEY
    material or one whose preset defines the profile."""
    if spec.method == "BURLEY" or _preset(spec) is not None:
        return None
    where = f"material {spec.name!r} (slot {spec.slot})"
    if "base_color" not in spec.options:
        raise ProfileError(
            f"{where}: the {spec.method} model needs option 'base_color' (3 numbers, linear)"
        )
    albedo = np.clip(_triple(spec, "base_color"), 0.0, 1.0)
    if "subsurface_radius" in spec.options:
        radius = _triple(spec, "subsurface_radius")
        scale = _number(spec, "subsurface_scale", 1.0)
    else:  # Blender's d = radius·scale/(4π)
        radius, scale = 4.0 * np.pi * np.asarray(spec.d, dtype=np.float64), 1.0
    ior = _number(spec, "subsurface_ior", 1.4)
    anisotropy = _number(spec, "subsurface_anisotropy", 0.0)
    try:
        d, e = random_walk.shape(radius, scale, albedo, spec.method, ior, anisotropy)
        ell = random_walk.mean_free_path(radius, scale, albedo, spec.method, ior)
    except ValueError as exc:
        raise ProfileError(f"{where}: {exc}") from None
    return d, albedo, ell, e


def _dipole_params(spec) -> tuple[np.ndarray, np.ndarray, float]:
    p = _preset(spec)
    if p is not None:
        return np.asarray(p.sigma_a), np.asarray(p.sigma_s), p.eta
    if {"sigma_a", "sigma_s"} <= set(spec.options):
        return (
            _triple(spec, "sigma_a"),
            _triple(spec, "sigma_s"),
            float(spec.options.get("eta", 1.3)),
        )
    raise ProfileError(
        f"material {spec.name!r} (slot {spec.slot}): the dipole profile needs a measured preset "
        f"(--material NAME or option 'preset': one of {', '.join(presets.names())}) or options "
        "'sigma_a', 'sigma_s' (mm^-1) and 'eta'"
    )


@functools.lru_cache(maxsize=64)
def _artist_from_dipole(sigma_a: tuple, sigma_s: tuple, eta: float, unit: float) -> tuple:
    prof = DipoleProfile(
        np.array([[0.0] * 3, sigma_a]),
        np.array([[0.0] * 3, sigma_s]),
        eta,
        unit=unit,
        single_scattering=False,
    )
    p = from_radial(radial_model(prof, 1))
    return tuple(tuple(p[k]) for k in ("strength", "near", "far", "weight"))


@functools.lru_cache(maxsize=64)
def _artist_from_burley(d: tuple, truncate: float) -> tuple:
    prof = BurleyProfile(np.array([[0.0] * 3, d]), truncate=truncate)
    p = from_radial(radial_model(prof, 1))
    return tuple(tuple(p[k]) for k in ("strength", "near", "far", "weight"))


def _artist_params(spec, truncate: float) -> np.ndarray:
    keys = ("strength", "near", "far", "weight")
    if all(k in spec.options for k in keys):
        return np.stack([_triple(spec, k) for k in keys])
    p = _preset(spec)
    if p is not None:
        derived = _artist_from_dipole(p.sigma_a, p.sigma_s, p.eta, _unit(spec))
    elif max(spec.d) > 0:
        d = np.asarray(spec.d, dtype=np.float64)
        d = np.where(d > 0, d, max(spec.d) * 1e-3)  # a zero channel would have no fit
        derived = _artist_from_burley(tuple(d), truncate)
    else:
        return np.stack([np.zeros(3), np.ones(3), np.ones(3), np.ones(3)])
    out = np.array(derived)
    if "strength" in spec.options:
        out[0] = _triple(spec, "strength")
    return out


def build_profile(
    materials: Mapping[int, object],
    n_slots: int,
    truncate: float = CYCLES_TRUNCATE,
    burley_inverse: str = "exact",
) -> Profile:
    """Profile for slots 0..n_slots−1 from MaterialSpecs (slot → spec; others do not scatter).

    Raises
    ------
    ValueError
        Unknown profile name, bad options or missing measured parameters;
        the message names the material and slot.
    """
    k = max([n_slots, *[s + 1 for s in materials]])
    kinds = {}
    for slot, spec in materials.items():
        if spec.profile not in PROFILE_NAMES:
            raise ProfileError(
                f"material {spec.name!r} (slot {slot}): profile must be one of "
                f"{', '.join(PROFILE_NAMES)}, got {spec.profile!r}"
            )
        kinds[slot] = spec.profile
    used = sorted(set(kinds.values())) or ["burley"]
    subs = {}
    walks: dict[int, tuple] = {}  # slot -> (method, albedo, ℓ, e) of random-walk materials
    for kind in used:
        mine = {s: m for s, m in materials.items() if kinds[s] == kind}
        if kind == "burley":
            d = np.zeros((k, 3))
            for s, spec in mine.items():
                walk = _random_walk(spec)
                if walk is None:
                    d[s] = _burley_d(spec)
                else:
                    d[s] = walk[0]
                    walks[s] = (spec.method, *walk[1:])
            subs[kind] = BurleyProfile(d, truncate=truncate, inverse=burley_inverse)
        elif kind == "dipole":
            sa, ss = np.zeros((k, 3)), np.zeros((k, 3))
            eta, unit = np.full(k, 1.3), np.full(k, 1.0 / MM_PER_METRE)
            single = {bool(spec.options.get("single_scattering", True)) for spec in mine.values()}
            if len(single) > 1:
                raise ProfileError("all dipole materials must agree on 'single_scattering'")
            for s, spec in mine.items():
                sa[s], ss[s], eta[s] = _dipole_params(spec)
                unit[s] = _unit(spec)
            try:
                subs[kind] = DipoleProfile(sa, ss, eta, unit, single_scattering=single.pop())
            except ValueError as exc:
                raise ProfileError(f"dipole materials: {exc}") from None
        else:
            tab = np.zeros((4, k, 3))
            tab[1:] = 1.0
            for s, spec in mine.items():
                tab[:, s] = _artist_params(spec, truncate)
            try:
                subs[kind] = ArtistProfile(*tab)
            except ValueError as exc:
                raise ProfileError(f"artist materials: {exc}") from None
    if len(subs) == 1:
        profile = next(iter(subs.values()))
    else:
        owner = np.zeros(k, dtype=np.intp)
        names = list(subs)
        for s, kind in kinds.items():
            owner[s] = names.index(kind)
        profile = MixedProfile([subs[n] for n in names], owner)
    if walks:
        methods = ["BURLEY"] * k
        albedo, ell, energy = np.zeros((k, 3)), np.zeros((k, 3)), np.ones((k, 3))
        for s, (method, a, mfp, e) in walks.items():
            methods[s], albedo[s], ell[s], energy[s] = method, a, mfp, e
        profile.energy = SlotEnergy(tuple(methods), albedo, ell, energy)
    return profile


def frame_profile(frame, params, choice: ProfileChoice | None = None) -> Profile:
    """The profile of a frame's materials (after ``choice``) over their compact slots.

    Slots are numbered as :func:`core.frame.compact_slots` numbers them, so
    the profile's tables grow with the number of materials, not with the
    largest Material Index.
    """
    materials = (
        frame.materials if choice is None or choice.is_default else choice.apply(frame.materials)
    )
    compact = compact_materials(materials)
    return build_profile(
        compact, len(compact) + 1, truncate=params.truncate, burley_inverse=params.burley_inverse
    )


class ProfileCache:
    """The profile of each frame, rebuilt only when the material table changes.

    Parameters
    ----------
    params : SSSParams (truncation, Burley sampler)
    choice : ProfileChoice or None
    """

    def __init__(self, params, choice: ProfileChoice | None = None):
        self.params = params
        self.choice = choice
        self._key = None
        self._profile: Profile | None = None

    def get(self, frame) -> Profile:
        key = tuple(
            sorted(
                (k, v.d, v.profile, v.method, repr(sorted(v.options.items())))
                for k, v in frame.materials.items()
            )
        )
        if key != self._key:
            try:
                self._profile = frame_profile(frame, self.params, self.choice)
            except ProfileError as exc:
                source = getattr(frame, "source", None)
                if not source:
                    raise
                # Name the file the materials came from (its sidecar).
                sidecar = os.fspath(Path(source).with_suffix(".json"))
                raise ProfileError(f"{exc} (the materials of {sidecar})") from None
            self._key = key
        return self._profile


def check_materials(
    materials: Mapping[int, object],
    choice: ProfileChoice | None = None,
    truncate: float = CYCLES_TRUNCATE,
) -> None:
    """Build the profile of ``materials`` (after ``choice``) once, to refuse bad setups early.

    Raises
    ------
    ProfileError
        As :func:`build_profile`.
    """
    if choice is not None and not choice.is_default:
        materials = choice.apply(materials)
    build_profile(materials, 1, truncate=truncate)


class MixedProfile(Profile):
    """Slots served by different profiles; each sample is dispatched to its slot's profile.

    Parameters
    ----------
    profiles : list of Profile, each with the same n_slots (rows they do not own
        must not scatter)
    owner : (K,) int, index into ``profiles`` per slot
    """

    name = "mixed"

    def __init__(self, profiles: list[Profile], owner: np.ndarray):
        self.profiles = list(profiles)
        self.owner = np.asarray(owner, dtype=np.intp)
        self.pixel_weight_scale = any(p.pixel_weight_scale for p in self.profiles)

    @property
    def n_slots(self) -> int:
        return self.owner.size

    def _pick(self, method: str) -> np.ndarray:
        out = None
        for i, p in enumerate(self.profiles):
            v = getattr(p, method)()
            out = v.copy() if out is None else out
            out[self.owner == i] = v[self.owner == i]
        return out

    def scatters(self):
        return self._pick("scatters")

    def chromatic(self):
        return self._pick("chromatic")

    def contact_scale(self):
        return self._pick("contact_scale")

    def region(self, r0, mat, backend="numpy"):
        r0 = np.asarray(r0, dtype=np.float64)
        mat = np.asarray(mat)
        n = r0.size
        out = Region(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.ones((n, 3)))
        who = self.owner[mat]
        for i, p in enumerate(self.profiles):
            sel = who == i
            if np.any(sel):
                reg = p.region(r0[sel], mat[sel])
                # Every profile's weight scale is γ/mass of its own pdf, so it is
                # right whether or not the estimator applies it.
                for f in ("gamma", "weight_scale", "lo", "hi"):
                    getattr(out, f)[sel] = getattr(reg, f)
        return out

    def sample(self, u, lo, hi, mat, channel):
        mat = np.asarray(mat)
        channel = np.broadcast_to(np.asarray(channel), mat.shape)
        r = np.zeros(mat.shape, dtype=np.float32)
        who = self.owner[mat]
        for i, p in enumerate(self.profiles):
            sel = who == i
            if np.any(sel):
                r[sel] = p.sample(u[sel], lo[sel], hi[sel], mat[sel], channel[sel])
        return r

    def pdf(self, r, mat):
        return self.pdf_channels(r, mat).T

    def pdf_channels(self, r, mat):
        r = np.asarray(r, dtype=np.float32)
        mat = np.asarray(mat)
        out = np.zeros((3, r.size), dtype=np.float32)
        who = self.owner[mat]
        for i, p in enumerate(self.profiles):
            sel = who == i
            if np.any(sel):
                out[:, sel] = p.pdf_channels(r[sel], mat[sel])
        return out

    def radial_model(self, slot: int) -> RadialModel:
        return radial_model(self.profiles[self.owner[int(slot)]], slot)

    def describe(self, slot):
        return self.profiles[self.owner[int(slot)]].describe(slot)
