"""Camera intrinsics that turn scene distances into pixels.

Frames travel with a :class:`Camera` (read from the sidecar JSON that the
add-on writes beside each pass EXR) so the core can compute the pixel
footprint at any depth without Blender.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

CAMERA_TYPES = ("PERSP", "ORTHO")
SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


@dataclass(frozen=True)
class Camera:
    """Pinhole or orthographic camera, Blender conventions.

    Attributes
    ----------
    width, height : int
        Rendered resolution in pixels (after the resolution percentage).
    type : {"PERSP", "ORTHO"}
    lens : float
        Focal length in millimetres (perspective).
    sensor_width, sensor_height : float
        Sensor size in millimetres.
    sensor_fit : {"AUTO", "HORIZONTAL", "VERTICAL"}
        Which image axis the sensor size (or ``ortho_scale``) spans; AUTO
        uses ``sensor_width`` along the larger of the two (aspect-corrected)
        dimensions, as Blender does.
    ortho_scale : float
        Extent of the orthographic view along the fitted axis, scene units.
    pixel_aspect_x, pixel_aspect_y : float
        Blender's pixel aspect ratio.
    clip_start, clip_end : float
        Clipping distances in scene units.
    shift_x, shift_y : float
        Blender's lens shift, in units of the larger image dimension; moves the
        principal point (x right, y up as in Blender).
    """

    width: int
    height: int
    type: str = "PERSP"
    lens: float = 50.0
    sensor_width: float = 36.0
    sensor_height: float = 24.0
    sensor_fit: str = "AUTO"
    ortho_scale: float = 6.0
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0
    clip_start: float = 0.1
    clip_end: float = 1000.0
    shift_x: float = 0.0
    shift_y: float = 0.0

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"camera {name} must be a positive integer, got {value!r}")
        if self.type not in CAMERA_TYPES:
            raise ValueError(f"camera type must be one of {CAMERA_TYPES}, got {self.type!r}")
        if self.sensor_fit not in SENSOR_FITS:
            raise ValueError(f"sensor_fit must be one of {SENSOR_FITS}, got {self.sensor_fit!r}")
        for name in ("shift_x", "shift_y"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise ValueError(f"camera {name} must be a finite number, got {value!r}")
        for name in (
            "lens",
            "sensor_width",
            "sensor_height",
            "ortho_scale",
            "pixel_aspect_x",
            "pixel_aspect_y",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"camera {name} must be a positive finite number, got {value!r}")

    def _fit_horizontal(self) -> bool:
        if self.sensor_fit == "AUTO":
            return self.width * self.pixel_aspect_x >= self.height * self.pixel_aspect_y
        return self.sensor_fit == "HORIZONTAL"

    def _unit_extent(self) -> tuple[float, float]:
        """Scene-unit size of one pixel (w, h) at unit depth (or always, ortho)."""
        horizontal = self._fit_horizontal()
        if self.type == "ORTHO":
            span = self.ortho_scale
        else:
            sensor = self.sensor_width
            if self.sensor_fit == "VERTICAL":
                sensor = self.sensor_height
            span = sensor / self.lens
        aspect = self.pixel_aspect_y / self.pixel_aspect_x
        if horizontal:
            w = span / self.width
            h = w * aspect
        else:
            h = span / self.height
            w = h / aspect
        return w, h

    def footprint(self, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel footprint (w, h) in scene units at planar depth ``depth``.

        Parameters
        ----------
        depth : (...) float array, scene units along the view axis

        Returns
        -------
        w, h : (...) float64 arrays, scene units per pixel horizontally and
            vertically. For perspective ``w = Z·2·tan(θ/2)/W``; for ortho the
            footprint does not depend on depth.
        """
        w, h = self._unit_extent()
        depth = np.asarray(depth, dtype=np.float64)
        if self.type == "ORTHO":
            return np.full(depth.shape, w), np.full(depth.shape, h)
        return depth * w, depth * h

    def unit_footprint(self) -> tuple[float, float]:
        """(w, h): pixel footprint in scene units at unit depth (perspective) or always (ortho)."""
        return self._unit_extent()

    @property
    def principal_point(self) -> tuple[float, float]:
        """(cx, cy): the optical axis in pixel coordinates (pixel centres at integers, y down)."""
        big = max(self.width * self.pixel_aspect_x, self.height * self.pixel_aspect_y)
        cx = 0.5 * (self.width - 1) - self.shift_x * big / self.pixel_aspect_x
        cy = 0.5 * (self.height - 1) + self.shift_y * big / self.pixel_aspect_y
        return cx, cy

    @property
    def horizontal_fov(self) -> float:
        """Horizontal field of view in radians (perspective only)."""
        w, _ = self._unit_extent()
        return 2.0 * math.atan(0.5 * w * self.width)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> Camera:
        known = {f for f in cls.__dataclass_fields__}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown camera fields: {sorted(unknown)}")
        return cls(**data)
