"""What a run computes: its methods, parameters and options (:class:`RunSpec`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..method import MethodOptions
from ..methods import get_method
from ..params import SSSParams

#: What a run does with results already in its folder (:mod:`core.run`).
EXISTING = ("error", "resume", "overwrite", "continue")


@dataclass(frozen=True)
class RunSpec:
    """What a run computes; a checkpoint resumes only a run with the same spec.

    Attributes
    ----------
    methods : method names, in the order given (the reference is added when
        ``reference`` is set, and always processed first)
    params : SSSParams
    options : MethodOptions
    reference : compute the reference (for PSNR) even if not in ``methods``
    reference_every : the reference (and PSNR) on the 1st, (k+1)-th, … frame only
    source : identity of the input (the resolved pass folder), part of the signature
    warmup_frames : frames processed before the first one to fill the history
        (:meth:`core.run.driver.SequenceRun.warm_up`); part of the signature when > 0
    """

    methods: tuple[str, ...]
    params: SSSParams = field(default_factory=SSSParams)
    options: MethodOptions = field(default_factory=MethodOptions)
    reference: bool = False
    reference_every: int = 1
    source: str = ""
    warmup_frames: int = 0

    def __post_init__(self) -> None:
        names = list(dict.fromkeys(self.methods))
        if not names:
            raise ValueError("at least one method is needed")
        for name in names:
            get_method(name)
        if (
            isinstance(self.reference_every, bool)
            or not isinstance(self.reference_every, int)
            or self.reference_every < 1
        ):
            raise ValueError(
                f"reference_every must be an integer >= 1, got {self.reference_every!r}"
            )
        if (
            isinstance(self.warmup_frames, bool)
            or not isinstance(self.warmup_frames, int)
            or self.warmup_frames < 0
        ):
            raise ValueError(f"warmup_frames must be an integer >= 0, got {self.warmup_frames!r}")
        object.__setattr__(self, "methods", tuple(names))

    @property
    def order(self) -> list[str]:
        """Processing order: the reference first (PSNR is then available at once)."""
        names = list(self.methods)
        need_ref = self.reference or "reference" in names
        return (["reference"] if need_ref else []) + [m for m in names if m != "reference"]

    def signature(self) -> dict:
        """What a checkpoint must share with the run that resumes it."""
        signature = {
            "source": self.source,
            "methods": self.order,
            "params": self.params.to_dict(),
            "options": self.options.to_dict(),
            "reference_every": self.reference_every,
        }
        if self.warmup_frames:
            # Only when used, so checkpoints of runs without warm-up still resume.
            signature["warmup_frames"] = self.warmup_frames
        return signature


def signature_difference(old: dict, new: dict) -> str:
    """What differs between a checkpoint's run signature ``old`` and this run's ``new``
    (:meth:`RunSpec.signature`), in a few words for an error message."""
    if old.get("source") != new["source"]:
        return f"passes from {old.get('source')}, now {new['source']}"
    if old.get("methods") != new["methods"]:
        methods = old.get("methods")
        methods = ",".join(map(str, methods)) if isinstance(methods, list) else repr(methods)
        return f"methods {methods}, now {','.join(new['methods'])}"
    if old.get("reference_every") != new["reference_every"]:
        return f"reference every {old.get('reference_every')} frames, now {new['reference_every']}"
    if old.get("warmup_frames", 0) != new.get("warmup_frames", 0):
        return f"warm-up {old.get('warmup_frames', 0)} frames, now {new.get('warmup_frames', 0)}"
    diffs = []
    for group in ("params", "options"):
        a, b = old.get(group), new[group]
        a = a if isinstance(a, dict) else {}
        diffs += [f"{k} {a.get(k)!r} -> {b[k]!r}" for k in b if a.get(k) != b[k]]
    return "parameters " + ", ".join(diffs)
