"""Pure-NumPy core of adaptive control-variate subsurface scattering.

Never imports ``bpy``: everything here runs and is tested without Blender.
References: Xie & Olano 2021 (P), Xie's defense slides (D), Jimenez et al.
2015 supplementary (S); see ``shared/SPEC.md``.
"""

from .camera import Camera
from .frame import Frame, MaterialSpec
from .mc.processor import FrameResult, SequenceProcessor
from .methods import METHODS, Method, get_method
from .params import ParameterError, SSSParams

__all__ = [
    "METHODS",
    "Camera",
    "Frame",
    "FrameResult",
    "MaterialSpec",
    "Method",
    "ParameterError",
    "SSSParams",
    "SequenceProcessor",
    "get_method",
]
