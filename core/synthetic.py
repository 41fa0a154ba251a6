"""Passes generated in code: tests, the benchmark and Blender-free demos.

The scenes are analytic stand-ins for rendered passes (same conventions as a
Blender frame: linear Rec. 709, planar depth in metres, EXR row order): a
non-SSS back wall, a skin-like sphere and a marble-like slab in front of it,
lit by a directional light whose intensity follows the demo scenes' rules,
with hard cast-shadow stripes and a soft terminator. A constant ambient term
stands in for the Diffuse Indirect pass.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from .camera import Camera
from .frame import Frame, MaterialSpec
from .profiles.burley import blender_shape

FPS = 60.0

#: Principled-style subsurface settings of the synthetic materials (scene units: m).
SKIN = {"radius": (1.0, 0.2, 0.1), "scale": 0.05, "albedo": (0.8, 0.55, 0.45)}
MARBLE = {"radius": (0.9, 0.8, 0.7), "scale": 0.03, "albedo": (0.85, 0.85, 0.8)}


def light_intensity(kind: str, frame: int) -> float:
    """Light intensity I(t) of the synthetic sequences at 60 fps.

    - ``static``: 1.
    - ``flash``: ``sin(2π·5·t) + 1`` (the paper's flash scene).
    - ``regular``: switched off for 3 s every 6 s (1 or 0.05), with a small
      candle-like flicker.
    """
    t = frame / FPS
    if kind == "static":
        return 1.0
    if kind == "flash":
        return math.sin(2.0 * math.pi * 5.0 * t) + 1.0
    if kind == "regular":
        on = (t % 6.0) < 3.0
        flicker = 0.08 * math.sin(2 * math.pi * 7.3 * t) * math.sin(2 * math.pi * 2.1 * t)
        return (1.0 if on else 0.05) + flicker
    raise ValueError(f"sequence kind must be 'static', 'flash' or 'regular', got {kind!r}")


def flat_plane(
    width: int = 64,
    height: int = 48,
    *,
    d: tuple[float, float, float] = (0.01, 0.004, 0.002),
    depth: float = 2.0,
    lighting: np.ndarray | None = None,
    number: int = 1,
) -> Frame:
    """A fronto-parallel single-material plane filling the view.

    Parameters
    ----------
    width, height : int, pixels
    d : Burley shape per channel, metres
    depth : float, metres
    lighting : (H, W, 3) float, B; default a unit constant
    number : int, frame number
    """
    cam = Camera(width=width, height=height)
    if lighting is None:
        lighting = np.ones((height, width, 3), np.float32)
    albedo = np.full((height, width, 3), 0.8, np.float32)
    return Frame(
        number=number,
        lighting=lighting,
        albedo=albedo,
        combined=albedo * lighting,
        depth=np.full((height, width), depth, np.float32),
        material=np.ones((height, width), np.int32),
        camera=cam,
        materials={1: MaterialSpec(1, "plane", d)},
    )


def _surface_frame(z: np.ndarray, cam: Camera, d, lighting, number: int) -> Frame:
    h, w = z.shape
    surface = np.isfinite(z) & (z > 0)
    if lighting is None:
        lighting = np.ones((h, w, 3), np.float32)
    albedo = np.full((h, w, 3), 0.8, np.float32)
    return Frame(
        number=number,
        lighting=lighting,
        albedo=albedo,
        combined=albedo * lighting,
        depth=np.where(surface, z, np.inf).astype(np.float32),
        material=surface.astype(np.int32),
        camera=cam,
        materials={1: MaterialSpec(1, "surface", d)},
    )


def _view_rays(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """x and y of the view ray through each pixel centre, per unit depth (y down)."""
    wu, hu = cam.unit_footprint()
    cx, cy = cam.principal_point
    yy, xx = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    return (xx - cx) * wu, (yy - cy) * hu


def tilted_plane(
    width: int = 64,
    height: int = 48,
    *,
    tilt: float = 60.0,
    depth: float = 2.0,
    d: tuple[float, float, float] = (0.01, 0.004, 0.002),
    lighting: np.ndarray | None = None,
    number: int = 1,
) -> Frame:
    """A single-material plane through (0, 0, ``depth``) turned by ``tilt`` degrees about
    the vertical axis (its right side recedes), seen by a 50 mm perspective camera.

    Depth is the exact ray-plane intersection per pixel centre (metres).
    """
    cam = Camera(width=width, height=height)
    rx, _ = _view_rays(cam)
    a = np.radians(tilt)
    with np.errstate(divide="ignore"):
        z = np.cos(a) * depth / (np.cos(a) - np.sin(a) * rx)
    z[(z <= 0) | (z > 1e3 * depth)] = np.inf
    return _surface_frame(z, cam, d, lighting, number)


def sphere(
    width: int = 64,
    height: int = 48,
    *,
    radius: float = 0.4,
    depth: float = 2.0,
    d: tuple[float, float, float] = (0.01, 0.004, 0.002),
    lighting: np.ndarray | None = None,
    number: int = 1,
) -> Frame:
    """A single-material sphere of ``radius`` centred at (0, 0, ``depth``) on an empty
    background, seen by a 50 mm perspective camera (exact ray-sphere depth, metres)."""
    cam = Camera(width=width, height=height)
    rx, ry = _view_rays(cam)
    dd = rx * rx + ry * ry + 1.0
    disc = depth * depth - dd * (depth * depth - radius * radius)
    with np.errstate(invalid="ignore"):
        z = (depth - np.sqrt(disc)) / dd
    z[~(disc >= 0)] = np.inf
    return _surface_frame(z, cam, d, lighting, number)


def _materials() -> dict[int, MaterialSpec]:
    return {
        1: MaterialSpec(1, "skin", tuple(blender_shape(SKIN["radius"], SKIN["scale"]))),
        2: MaterialSpec(2, "marble", tuple(blender_shape(MARBLE["radius"], MARBLE["scale"]))),
    }


def scene_frame(
    kind: str,
    number: int,
    width: int = 320,
    height: int = 180,
    *,
    coverage: float | None = None,
) -> Frame:
    """One frame of the synthetic sequence ``kind`` (see :func:`light_intensity`).

    Parameters
    ----------
    kind : {"static", "flash", "regular"}
    number : int, frame number (60 fps)
    width, height : int, pixels
    coverage : float in (0, 1], optional
        If given, replace the objects by a centred SSS rectangle covering this
        share of the image (benchmark of work against SSS coverage).
    """
    cam = Camera(width=width, height=height, lens=50.0, sensor_width=36.0)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    # Normalised image coordinates in [-1, 1] horizontally, y down.
    u = (xx + 0.5) / width * 2.0 - 1.0
    v = (yy + 0.5) / height * 2.0 - 1.0
    aspect = height / width
    depth = np.full((height, width), 4.0)
    material = np.zeros((height, width), np.int32)
    normal = np.zeros((height, width, 3))
    normal[..., 2] = 1.0
    if coverage is not None:
        if not 0 < coverage <= 1:
            raise ValueError(f"coverage must be in (0, 1], got {coverage}")
        side = math.sqrt(coverage)
        inside = (np.abs(u) <= side) & (np.abs(v) <= side)
        material[inside] = 1
        depth[inside] = 2.5
    else:
        # Sphere (skin), radius 0.45 m at 2.5 m, left of centre.
        cx, cy, rad = -0.35, 0.0, 0.42
        du, dv = (u - cx), (v - cy) * aspect
        rr = du * du + dv * dv
        sphere = rr < (rad * rad)
        nz = np.sqrt(np.clip(1.0 - rr / (rad * rad), 0.0, 1.0))
        material[sphere] = 1
        depth[sphere] = 2.5 - 0.45 * nz[sphere]
        normal[sphere, 0] = du[sphere] / rad
        normal[sphere, 1] = -dv[sphere] / rad
        normal[sphere, 2] = nz[sphere]
        # Slab (marble), right of centre, slightly tilted in depth.
        slab = (u > 0.2) & (u < 0.85) & (v > -0.55) & (v < 0.65)
        material[slab] = 2
        depth[slab] = 3.0 + 0.3 * u[slab]
    light_dir = np.array([0.5, 0.45, 0.74])
    light_dir /= np.linalg.norm(light_dir)
    lambert = np.clip(normal @ light_dir, 0.0, 1.0)
    # Hard cast-shadow stripes (G = 0 regions) plus a soft shadow gradient.
    stripes = ((np.floor((u + 0.4 * v) * 6.0) % 3) != 0).astype(np.float64)
    soft = 0.5 + 0.5 * np.tanh((u - 0.55 * v) * 4.0)
    intensity = light_intensity(kind, number)
    direct = intensity * 1.2 * lambert * stripes * (0.35 + 0.65 * soft)
    ambient = 0.06
    b = np.repeat((direct + ambient)[..., None], 3, axis=2)
    b *= np.array([1.0, 0.97, 0.92])
    albedo = np.full((height, width, 3), 0.5)
    albedo[material == 1] = SKIN["albedo"]
    albedo[material == 2] = MARBLE["albedo"]
    depth[material == 0] = 4.0
    # One object per material, the wall last (Blender's Object Index pass): they
    # stand well apart in depth, so none touches another.
    objects = np.where(material > 0, material, material.max() + 1).astype(np.int32)
    return Frame(
        number=number,
        lighting=b.astype(np.float32),
        albedo=albedo.astype(np.float32),
        combined=(albedo * b).astype(np.float32),
        depth=depth.astype(np.float32),
        material=material,
        camera=cam,
        materials=_materials() if coverage is None else {1: _materials()[1]},
        objects=objects,
    )


def sequence(
    kind: str, frames: int, width: int = 320, height: int = 180, start: int = 1, **kw
) -> Iterator[Frame]:
    """Frames ``start .. start+frames−1`` of a synthetic sequence."""
    for n in range(start, start + frames):
        yield scene_frame(kind, n, width, height, **kw)


def moving_frame(
    number: int,
    width: int = 96,
    height: int = 64,
    step: tuple[int, int] = (3, 2),
    offscreen_rows: int = 0,
) -> Frame:
    """The ``flash`` sequence translated ``step`` pixels (x, y) per frame, with motion vectors.

    Content wraps around the image (``np.roll``); the motion vectors (pixels,
    Blender's convention: towards the previous frame) carry a smooth sub-pixel
    jitter so that reprojection interpolates. The top ``offscreen_rows`` rows
    get vectors pointing far off the image (a disocclusion marker). For tests
    and benchmarks of history handling across tile borders.
    """
    base = scene_frame("flash", number, width, height)
    yy, xx = np.mgrid[0:height, 0:width]
    jitter = 0.45 * np.sin(0.7 * xx + 1.3 * yy + number)
    motion = np.stack([-step[0] + jitter, -step[1] - jitter], axis=-1).astype(np.float32)
    motion[:offscreen_rows, :] = 1e7

    return base.map_pixels(
        lambda a: np.roll(a, (step[1] * number, step[0] * number), axis=(0, 1)), motion=motion
    )
