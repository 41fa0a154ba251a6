"""What a post-processing method is, and what its processor offers.

:class:`Method` describes one method (how it picks sample counts, its control
variate, its temporal reuse); the registry of all of them is :mod:`core.methods`.
A *processor* carries one method's state (the per-pixel history) from frame to
frame; every processor has the same interface (:class:`Processor`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from .frame import Frame
from .params import SeparableParams
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
    """

    name: str
    label: str
    description: str
    kind: str
    cv: str = "none"
    temporal: str = ""

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
