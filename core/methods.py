"""The one method registry: name → what the method is and the processor that runs it.

The same table feeds the sequence driver (core.run), the Blender EnumProperty
items, the command-line choices and the report columns, so a method added
here shows up everywhere at once.
"""

from __future__ import annotations

from .mc.processor import MonteCarloProcessor
from .method import Method, MethodOptions, Processor
from .params import SSSParams
from .separable.processor import SeparableProcessor

#: The processor class of each kind of method (:attr:`Method.kind`).
PROCESSORS = {
    "none": MonteCarloProcessor,
    "fixed": MonteCarloProcessor,
    "adaptive": MonteCarloProcessor,
    "reference": MonteCarloProcessor,
    "separable": SeparableProcessor,
}

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
    return PROCESSORS[method.kind](method, params or SSSParams(), options or MethodOptions())


def enum_items() -> list[tuple[str, str, str]]:
    """Items for a Blender ``EnumProperty`` (identifier, name, description)."""
    return [(m.name, m.label, m.description) for m in METHODS.values()]
