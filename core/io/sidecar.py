"""The sidecar JSON that travels beside each pass EXR: camera, materials, engine.

``0003.exr`` + ``0003.json``, written by the add-on (or :func:`core.io.exr.write_passes`)::

    {"format": "cvsss-passes/1", "frame": 3, "camera": {...Camera.to_dict()},
     "materials": [{...MaterialSpec.to_dict()}, ...], "scene_unit_scale": 1.0,
     "view_layer": "ViewLayer", "engine": "CYCLES"}
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..camera import Camera
from ..frame import MaterialSpec
from .atomic import write_files
from .errors import PassError

#: Value of the sidecar's ``format`` field.
SIDECAR_FORMAT = "cvsss-passes/1"

#: View layer name used by :func:`core.io.exr.write_passes`.
DEFAULT_VIEW_LAYER = "ViewLayer"


def make_sidecar(
    camera: Camera,
    materials: Mapping[int, MaterialSpec] | list[MaterialSpec] = (),
    *,
    frame: int | None = None,
    view_layer: str = DEFAULT_VIEW_LAYER,
    engine: str = "CYCLES",
    scene_unit_scale: float = 1.0,
) -> dict:
    """The sidecar dictionary that goes next to a pass EXR.

    Parameters
    ----------
    camera : Camera
    materials : mapping slot -> MaterialSpec, or sequence of MaterialSpec
    frame : int, optional
        Frame number.
    view_layer : str
        Name of the view layer whose passes the EXR holds.
    engine : str
        Render engine identifier (``"CYCLES"``, ``"BLENDER_EEVEE_NEXT"``, …).
    scene_unit_scale : float
        Blender's unit scale (metres per scene unit), > 0.

    Returns
    -------
    dict
        JSON-serialisable; see the module docstring for the layout.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a Camera, got {type(camera).__name__}")
    specs = list(materials.values()) if isinstance(materials, Mapping) else list(materials)
    if not (math.isfinite(scene_unit_scale) and scene_unit_scale > 0):
        raise ValueError(
            f"scene_unit_scale must be a positive finite number, got {scene_unit_scale}"
        )
    data = {"format": SIDECAR_FORMAT}
    if frame is not None:
        data["frame"] = int(frame)
    data.update(
        {
            "camera": camera.to_dict(),
            "materials": [spec.to_dict() for spec in specs],
            "scene_unit_scale": float(scene_unit_scale),
            "view_layer": str(view_layer),
            "engine": str(engine),
        }
    )
    return data


@dataclass(frozen=True)
class Sidecar:
    """Validated content of a sidecar JSON.

    Attributes
    ----------
    camera : Camera
    materials : dict[int, MaterialSpec]
    frame : int or None
    view_layer : str or None
    engine : str or None
    scene_unit_scale : float
    raw : dict
        The JSON object as read.
    """

    camera: Camera
    materials: dict[int, MaterialSpec]
    frame: int | None
    view_layer: str | None
    engine: str | None
    scene_unit_scale: float
    raw: dict


def read_sidecar(path: str | os.PathLike, exr_path: str | os.PathLike | None = None) -> Sidecar:
    """Read and validate a sidecar JSON.

    Parameters
    ----------
    path : str or PathLike
        The ``.json`` file.
    exr_path : str or PathLike, optional
        The pass EXR it belongs to (only used in the missing-file message).

    Returns
    -------
    Sidecar

    Raises
    ------
    PassError
        Missing, unreadable or invalid sidecar; the message names it.
    """
    path = Path(path)
    name = os.fspath(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        where = f" next to {os.fspath(exr_path)}" if exr_path is not None else ""
        raise PassError(f"{name}: missing camera sidecar{where}") from None
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise PassError(f"{name}: cannot read camera sidecar ({reason})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PassError(f"{name}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise PassError(f"{name}: expected a JSON object, got {type(data).__name__}")
    fmt = data.get("format")
    if fmt != SIDECAR_FORMAT:
        raise PassError(f"{name}: unsupported format {fmt!r} (expected {SIDECAR_FORMAT!r})")
    if not isinstance(data.get("camera"), dict):
        raise PassError(f"{name}: missing or invalid 'camera' object")
    try:
        camera = Camera.from_dict(data["camera"])
    except (TypeError, ValueError) as exc:
        raise PassError(f"{name}: invalid camera ({exc})") from None
    raw_materials = data.get("materials", [])
    if not isinstance(raw_materials, list):
        raise PassError(f"{name}: 'materials' must be a list")
    materials: dict[int, MaterialSpec] = {}
    for i, entry in enumerate(raw_materials):
        try:
            if not isinstance(entry, dict):
                raise TypeError(f"expected an object, got {type(entry).__name__}")
            spec = MaterialSpec.from_dict(entry)
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            detail = f"missing {exc}" if isinstance(exc, KeyError) else str(exc)
            raise PassError(f"{name}: invalid material #{i} ({detail})") from None
        if spec.slot in materials:
            raise PassError(f"{name}: material slot {spec.slot} is listed twice")
        materials[spec.slot] = spec
    frame = data.get("frame")
    if frame is not None and (isinstance(frame, bool) or not isinstance(frame, int)):
        raise PassError(f"{name}: 'frame' must be an integer, got {frame!r}")
    scale = data.get("scene_unit_scale", 1.0)
    if (
        isinstance(scale, bool)
        or not isinstance(scale, int | float)
        or not (math.isfinite(scale) and scale > 0)
    ):
        raise PassError(f"{name}: 'scene_unit_scale' must be a positive number, got {scale!r}")
    view_layer = data.get("view_layer")
    if view_layer is not None and not isinstance(view_layer, str):
        raise PassError(f"{name}: 'view_layer' must be a string, got {view_layer!r}")
    engine = data.get("engine")
    return Sidecar(
        camera=camera,
        materials=materials,
        frame=frame,
        view_layer=view_layer,
        engine=None if engine is None else str(engine),
        scene_unit_scale=float(scale),
        raw=data,
    )


def write_sidecar(path: str | os.PathLike, sidecar: Mapping, overwrite: bool = False) -> None:
    """Write a sidecar dictionary (see :func:`make_sidecar`) as JSON, atomically.

    Parameters
    ----------
    path : str or PathLike
        The ``.json`` file (the pass EXR's path with suffix ``.json``).
    sidecar : mapping
    overwrite : bool

    Raises
    ------
    FileExistsError, OutputError
        As for :func:`write_passes`.
    """
    path = Path(path)
    if path.suffix.lower() != ".json":
        raise ValueError(f"sidecar file must end in .json, got {os.fspath(path)!r}")
    if sidecar.get("format") != SIDECAR_FORMAT:
        raise ValueError(
            f"sidecar format must be {SIDECAR_FORMAT!r}, got {sidecar.get('format')!r}"
        )
    text = (json.dumps(dict(sidecar), indent=2) + "\n").encode("utf-8")
    write_files([(path, text)], overwrite)
