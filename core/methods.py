"""The one method table: name → what the method does.

The same table feeds the pipeline's dispatch, the Blender EnumProperty items,
the command-line choices and the report columns, so a method added here shows
up everywhere at once.
"""

from __future__ import annotations

from dataclasses import dataclass


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
    counts : {"none", "fixed", "reference", "adaptive", "separable"}
        How per-pixel sample counts are chosen.
    cv : {"none", "online", "constant"}
        Control variate applied to the tracked value (adaptive only).
    """

    name: str
    label: str
    description: str
    counts: str
    cv: str = "none"

    @property
    def adaptive(self) -> bool:
        return self.counts == "adaptive"

    @property
    def monte_carlo(self) -> bool:
        """True when the method draws distant-scattering samples."""
        return self.counts in ("fixed", "reference", "adaptive")


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
    except KeyError:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {name!r}") from None


def enum_items() -> list[tuple[str, str, str]]:
    """Items for a Blender ``EnumProperty`` (identifier, name, description)."""
    return [(m.name, m.label, m.description) for m in METHODS.values()]
