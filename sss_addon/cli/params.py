"""Command-line flags generated from the parameter specs of core.params.

Every parameter with a flag in its :class:`~cvsss.core.params.Spec` becomes a
``--flag`` with the spec's help text, range and unit; values left unset keep
the dataclass default (or the scene's setting, for ``cvsss render``).
"""

from __future__ import annotations

import argparse
from dataclasses import MISSING

from ...core.method import MethodOptions
from ...core.params import SeparableParams, SSSParams, flag_of, specs
from ...core.profiles.factory import ProfileChoice

#: (group, dataclass, argparse title) of the parameters on the command line.
GROUPS = (
    ("params", SSSParams, "algorithm parameters (defaults: the paper's)"),
    ("profile", ProfileChoice, "diffusion profile and measured materials"),
    ("separable", SeparableParams, "separable SSS (method separable)"),
)


class UserError(Exception):
    """A problem the user can fix; printed as one line, exit status 2."""


def _dest(group: str, name: str) -> str:
    return f"{group}__{name}"


def _bool(text: str) -> bool:
    low = text.strip().lower()
    if low in ("1", "true", "yes", "on"):
        return True
    if low in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """One ``--flag`` per parameter of every group (plus ``--material``)."""
    for group, cls, title in GROUPS:
        arguments = parser.add_argument_group(title)
        for f, spec in specs(cls):
            flag = flag_of(f, spec)
            if not flag:
                continue
            default = f.default if f.default is not MISSING else None
            text = spec.describe() + (f" (default {default})" if default is not None else "")
            text = text.replace("%", "%%")  # argparse formats help with %: "7 %" is text
            kwargs = {"dest": _dest(group, f.name), "default": None, "help": text}
            if spec.choices is not None:
                # Checked by the dataclass, so a bad value is one error naming the flag.
                listing = ",".join(map(str, spec.choices))
                kwargs.update(type=type(spec.choices[0]), metavar=f"{{{listing}}}")
            elif f.type in ("bool", bool):
                kwargs.update(type=_bool, nargs="?", const=True, metavar="BOOL")
            else:
                integer = f.type in ("int", "int | None")
                kwargs["type"] = int if integer else float
                kwargs["metavar"] = "N" if integer else "X"
            arguments.add_argument(f"--{flag}", **kwargs)
        if cls is ProfileChoice:
            material = next(s for f, s in specs(ProfileChoice) if f.name == "material")
            arguments.add_argument(
                "--material",
                dest=_dest(group, "material"),
                default=None,
                metavar="PRESET|SLOT=PRESET,...",
                help=material.help.replace("%", "%%"),
            )


def overrides(args: argparse.Namespace, group: str) -> dict:
    """The values of ``group`` given on the command line (unset flags left out)."""
    cls = next(c for g, c, _ in GROUPS if g == group)
    out = {}
    for f, _ in specs(cls):
        value = getattr(args, _dest(group, f.name), None)
        if value is not None:
            out[f.name] = value
    return out


def params_from_args(args: argparse.Namespace) -> SSSParams:
    """SSSParams from the flags (unset flags keep the paper's defaults)."""
    return SSSParams(**overrides(args, "params"))


def options_from_args(args: argparse.Namespace) -> MethodOptions:
    """MethodOptions (profile choice and separable kernel) from the flags.

    Raises
    ------
    UserError
        An unknown preset or a malformed ``--material``.
    """
    profile = overrides(args, "profile")
    try:
        if "material" in profile:
            profile["material"], profile["slot_materials"] = ProfileChoice.parse_material(
                profile["material"]
            )
        choice = ProfileChoice(**profile)
    except ValueError as exc:
        raise UserError(f"--material/--profile: {exc}") from None
    return MethodOptions(
        profile=None if choice.is_default else choice,
        separable=SeparableParams(**overrides(args, "separable")),
    )


def flag_for_field(name: str) -> str | None:
    """The ``--flag`` of a parameter field (for error messages that name the field)."""
    for _, cls, _ in GROUPS:
        for f, spec in specs(cls):
            if f.name == name and flag_of(f, spec):
                return f"--{flag_of(f, spec)}"
    return None
