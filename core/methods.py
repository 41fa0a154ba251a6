"""The one method registry: name → what the method is and how to build its processor.

The same table feeds the sequence driver (core.run), the Blender EnumProperty
items, the command-line choices and the report columns, so a method added
here shows up everywhere at once. Importing this module imports no estimator:
each entry's factory loads its implementation when a processor is built.

A *processor* carries one method's state (the per-pixel history) from frame to
frame; every processor has the same interface (:class:`Processor`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from .params import SeparableParams, SSSParams

if TYPE_CHECKING:
    from .frame import Frame
    from .profiles.factory import ProfileChoice
    from .result import FrameResult

#: XOR salt giving the reference its own random stream.
REFERENCE_SALT = 0x9E3779B9


class Processor(Protocol):
    """What every method's processor offers the sequence driver."""

    method: Method

    def process(self, frame: Frame) -> FrameResult:
        """Post-process the next frame of the sequence."""

    def state(self) -> dict[str, np.ndarray]:
        """The state carried to the next frame, as named arrays (empty: stateless)."""

    def restore(self, state: Mapping[str, np.ndarray]) -> None:
        """Continue from a :meth:`state` (bit for bit)."""


@dataclass(frozen=True)
class MethodOptions:
    """Settings beyond :class:`SSSParams` that some methods take.

    Attributes
    ----------
    profile : core.profiles.factory.ProfileChoice or None
        Profile / measured material for every slot (None: each material's own).
    separable : SeparableParams
        Kernel, taps and jitter of the ``separable`` method.
    """

    profile: ProfileChoice | None = None
    separable: SeparableParams = field(default_factory=SeparableParams)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (run signatures, reports)."""
        profile = None
        if self.profile is not None and not self.profile.is_default:
            profile = self.profile.to_dict()
        return {"profile": profile, "separable": self.separable.to_dict()}


Factory = Callable[["Method", SSSParams, MethodOptions], Processor]


def _monte_carlo(method: Method, params: SSSParams, options: MethodOptions) -> Processor:
    from .mc.processor import MonteCarloProcessor

    return MonteCarloProcessor(method, params, options)


def _separable(method: Method, params: SSSParams, options: MethodOptions) -> Processor:
    from .separable.processor import SeparableProcessor

    return SeparableProcessor(method, params, options)


@dataclass(frozen=True)
class Method:
    """A post-processing method.

    Attributes
    ----------
    name : str
        Identifier used on the command line, in files and in the UI enum.
    label : str
        Short human-readable name.
    description : str
        Tooltip / help text.
    kind : {"none", "fixed", "reference", "adaptive", "separable"}
        How per-pixel sample counts are chosen.
    cv : {"none", "online", "constant"}
        Control variate applied to the tracked value (adaptive only).
    temporal : {"", "plain", "guided"}
        Temporal reuse of the distant estimate (core.mc.temporal): none, plain
        accumulation, or guided by the control (``SSSParams.temporal_mode``).
    factory : callable (Method, SSSParams, MethodOptions) -> Processor
    """

    name: str
    label: str
    description: str
    kind: str
    cv: str = "none"
    temporal: str = ""
    factory: Factory = field(default=_monte_carlo, repr=False, compare=False)

    @property
    def adaptive(self) -> bool:
        return self.kind == "adaptive"

    @property
    def monte_carlo(self) -> bool:
        """True when the method draws distant-scattering samples."""
        return self.kind in ("fixed", "reference", "adaptive")

    @property
    def seed_salt(self) -> int:
        """XORed into the seed: the reference draws an independent stream."""
        return REFERENCE_SALT if self.kind == "reference" else 0


METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        Method(
            "none", "Diffuse", "No subsurface scattering: the diffuse passes as rendered", "none"
        ),
        Method(
            "fixed",
            "Fixed N",
            "Burley importance sampling with the same N samples per pixel",
            "fixed",
        ),
        Method("as", "AS", "SPVG adaptive sample counts from the per-pixel history", "adaptive"),
        Method(
            "as_ocv",
            "AS + OCV",
            "Adaptive counts tracking the residual of an online control variate (EMCM)",
            "adaptive",
            "online",
        ),
        Method(
            "as_ccv",
            "AS + CCV",
            "Adaptive counts tracking the residual of a constant control variate (alpha = 1)",
            "adaptive",
            "constant",
        ),
        Method(
            "as_t",
            "AS + Temporal",
            "Adaptive counts, then plain temporal accumulation of the estimate "
            "(reprojected, clamped to the neighbourhood): the ghosting baseline",
            "adaptive",
            temporal="plain",
        ),
        Method(
            "as_ocv_t",
            "AS + OCV + Temporal",
            "Online control variate, then temporal reuse guided by the control and a "
            "noise-free proxy (no lag when lights flash)",
            "adaptive",
            "online",
            temporal="guided",
        ),
        Method(
            "as_ccv_t",
            "AS + CCV + Temporal",
            "Constant control variate, then temporal reuse guided by the control and a "
            "noise-free proxy (no lag when lights flash)",
            "adaptive",
            "constant",
            temporal="guided",
        ),
        Method(
            "reference",
            "Reference",
            "Many samples per pixel (default 1024) from an independent random stream",
            "reference",
        ),
        Method(
            "separable",
            "Separable",
            "Jimenez et al. 2015 separable SSS: two 1D passes per kernel term "
            "(pre-integrated, SVD rank-k, sum of Gaussians or artist kernel)",
            "separable",
            factory=_separable,
        ),
    )
}


def get_method(name: str) -> Method:
    """Look up a method by name with an error listing the valid names."""
    try:
        return METHODS[name]
    except (KeyError, TypeError):
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {name!r}") from None


def make_processor(
    name: str, params: SSSParams | None = None, options: MethodOptions | None = None
) -> Processor:
    """A fresh processor (empty history) of method ``name``.

    Parameters
    ----------
    name : str, a key of :data:`METHODS`
    params : SSSParams, default the paper's
    options : MethodOptions, default each material's own profile and the
        default separable kernel
    """
    method = get_method(name)
    return method.factory(method, params or SSSParams(), options or MethodOptions())


def enum_items() -> list[tuple[str, str, str]]:
    """Items for a Blender ``EnumProperty`` (identifier, name, description)."""
    return [(m.name, m.label, m.description) for m in METHODS.values()]
