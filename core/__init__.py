"""Pure-NumPy core of adaptive control-variate subsurface scattering.

Never imports ``bpy``: everything here runs and is tested without Blender.
References: Xie & Olano 2021 (P), Xie's defense slides (D), Jimenez et al.
2015 supplementary (S); the design, in the repository's own words, is
docs/explanation/design.md.
"""

from .camera import Camera
from .frame import Frame, MaterialSpec
from .method import Method, MethodOptions
from .methods import METHODS, get_method, make_processor
from .params import ParameterError, SeparableParams, SSSParams
from .result import FrameResult

__all__ = [
    "METHODS",
    "Camera",
    "Frame",
    "FrameResult",
    "MaterialSpec",
    "Method",
    "MethodOptions",
    "ParameterError",
    "SSSParams",
    "SeparableParams",
    "get_method",
    "make_processor",
]
