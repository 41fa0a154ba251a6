"""OpenEXR input and output: Blender pass files, their sidecars, and results.

A *pass file* is the multilayer EXR that Blender writes for one frame, plus a
sidecar JSON of the same stem (``0003.exr`` + ``0003.json``, see
:mod:`.sidecar`) with the camera and the subsurface materials.

Channel names are discovered from the header, never hard-coded. Blender 5
writes one part per pass (``ViewLayer.Diffuse Direct`` holding channels
``ViewLayer.Diffuse Direct.R/G/B``); older versions write a single part and
short pass names (``DiffDir``, ``DiffInd``, ``DiffCol``, ``IndexMA``). The view
layer prefix is detected; when a file holds several view layers the sidecar's
``view_layer`` picks one.

Pixel arrays use the EXR convention of :mod:`cvsss.core.frame`: row 0 is the
top of the image. Every file is written atomically (:mod:`.atomic`), and
existing files are only replaced when asked.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import sys
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenEXR

from ..frame import Frame
from ..result import FrameResult
from .atomic import write_files
from .errors import PassError, exists_error
from .sidecar import DEFAULT_VIEW_LAYER, make_sidecar, read_sidecar

__all__ = [
    "BACKGROUND_DEPTH_WRITTEN",
    "REQUIRED_PASSES",
    "THIN_PIXEL_SHARE",
    "THIN_POINT_AOV",
    "list_frames",
    "motion_from_vector",
    "quiet_native_stderr",
    "read_channels",
    "read_combined",
    "read_frame",
    "read_pass",
    "read_result",
    "use_threads",
    "vector_from_motion",
    "write_passes",
    "write_result",
]

#: Depth written for background pixels, as Blender does.
BACKGROUND_DEPTH_WRITTEN = 1e10

#: Value AOV the pass render writes: 1 at points whose subsurface Cycles renders.
THIN_POINT_AOV = "cvsss_thin"

# Canonical pass name -> names it has had in Blender's EXR output.
_PASS_ALIASES: dict[str, tuple[str, ...]] = {
    "Combined": ("Combined",),
    "Depth": ("Depth", "Z"),
    "Diffuse Direct": ("Diffuse Direct", "DiffDir"),
    "Diffuse Indirect": ("Diffuse Indirect", "DiffInd"),
    "Diffuse Color": ("Diffuse Color", "DiffCol"),
    "Material Index": ("Material Index", "IndexMA"),
    "Object Index": ("Object Index", "IndexOB"),
    "Vector": ("Vector",),
    # Value AOV the pass render writes where a material's Subsurface Weight is linked.
    "SSS Weight": ("cvsss_weight",),
    "Thin Points": (THIN_POINT_AOV,),
}
_ALIAS_TO_PASS = {alias: name for name, aliases in _PASS_ALIASES.items() for alias in aliases}
# Longest first so that "Diffuse Direct" wins over a hypothetical shorter suffix.
_ALIASES_BY_LENGTH = sorted(_ALIAS_TO_PASS, key=len, reverse=True)

# Channels each pass must hold. Single-channel passes accept any one channel.
_PASS_CHANNELS: dict[str, tuple[str, ...]] = {
    "Combined": ("R", "G", "B"),
    "Depth": ("Z",),
    "Diffuse Direct": ("R", "G", "B"),
    "Diffuse Indirect": ("R", "G", "B"),
    "Diffuse Color": ("R", "G", "B"),
    "Material Index": ("X",),
    "Object Index": ("X",),
    "Vector": ("X", "Y", "Z", "W"),
    "SSS Weight": ("X",),
    "Thin Points": ("X",),
}

#: A pixel at least this share of whose samples were thin points (the pass render's
#: ``cvsss_thin`` AOV, sss_addon.blender.thin_parts) takes no part: Cycles rendered its
#: subsurface, and the post leaves it as rendered. Nearly all, not most: the pass render
#: holds the other samples' Subsurface Weight at 0, so a pixel left as rendered lacks
#: their share of its subsurface, while the post composites a partly thin pixel without
#: such a loss. At half, the rims' partly thin pixels along the demo's marble top came
#: out darker than the ground truth (docs/explanation/accuracy.md §2.3).
THIN_PIXEL_SHARE = 0.9

#: Passes read_frame cannot do without (canonical Blender 5 names).
REQUIRED_PASSES = ("Combined", "Depth", "Diffuse Direct", "Diffuse Color", "Material Index")

# Result layers: layer name -> (FrameResult field, channels).
_RESULT_LAYERS: dict[str, tuple[str, tuple[str, ...]]] = {
    "Composite": ("composite", ("R", "G", "B")),
    "SSS": ("sss", ("R", "G", "B")),
    "Gamma": ("gamma", ("R", "G", "B")),
    "SampleCount": ("counts", ("V",)),
    "Alpha": ("alpha", ("V",)),
    "Variance": ("variance", ("V",)),
    "ValidHistory": ("valid_history", ("V",)),
    "Mask": ("mask", ("V",)),
}
# FrameResult scalars stored as header strings next to the method and frame.
_RESULT_STATS = (
    "spp",
    "samples",
    "sampling_ms",
    "update_ms",
    "total_ms",
    "distant_share",
    "fallback_share",
    "repaired",
)
_RESERVED_KEYS = frozenset(("method", "frame", *_RESULT_STATS))

_FRAME_NAME = re.compile(r"^(\d+)\.exr$", re.IGNORECASE)
_EXR_MAGIC = b"\x76\x2f\x31\x01"


# -- motion vectors ------------------------------------------------------------------
def motion_from_vector(vector: np.ndarray) -> np.ndarray:
    """Frame motion from Blender's Vector pass.

    Blender 5.0 / Cycles convention (checked by rendering an object moving by
    a known number of pixels): X, Y are the previous position minus the
    current one, in pixels, with x to the right and y *up*; Z, W are the
    current minus the next position. A surface seen at EXR row i, column j
    was at row ``i − Y``, column ``j + X`` in the previous frame. The motion
    of a :class:`Frame` points to that previous position in EXR rows (y
    down), hence ``(dx, dy) = (X, −Y)``; Z, W are not used.

    Parameters
    ----------
    vector : (H, W, 4) float array
        Vector pass channels X, Y, Z, W in pixels.

    Returns
    -------
    (H, W, 2) float32
        ``(dx, dy)`` in pixels, x right, y down.

    Examples
    --------
    >>> v = np.zeros((1, 1, 4), np.float32); v[0, 0, :2] = (3.0, 2.0)
    >>> motion_from_vector(v)[0, 0].tolist()
    [3.0, -2.0]
    """
    v = np.asarray(vector)
    if v.ndim != 3 or v.shape[2] != 4:
        raise ValueError(f"vector must have shape (H, W, 4), got {v.shape}")
    out = np.empty((*v.shape[:2], 2), dtype=np.float32)
    out[..., 0] = v[..., 0]
    out[..., 1] = -v[..., 1]
    return out


def vector_from_motion(motion: np.ndarray) -> np.ndarray:
    """Inverse of :func:`motion_from_vector`: a Vector pass from frame motion.

    Parameters
    ----------
    motion : (H, W, 2) float array
        ``(dx, dy)`` in pixels, x right, y down, as in :class:`Frame`.

    Returns
    -------
    (H, W, 4) float32
        Vector pass channels X, Y, Z, W; Z and W (motion to the next frame,
        which a Frame does not carry) are 0.
    """
    m = np.asarray(motion)
    if m.ndim != 3 or m.shape[2] != 2:
        raise ValueError(f"motion must have shape (H, W, 2), got {m.shape}")
    out = np.zeros((*m.shape[:2], 4), dtype=np.float32)
    out[..., 0] = m[..., 0]
    out[..., 1] = -m[..., 1]
    return out


def use_threads() -> int:
    """Let OpenEXR (de)compress a file's blocks on every core this process may use.

    The bindings' library starts with no worker threads, so a ZIP-compressed
    file was written and read on one core: at 1280×720 a result EXR took about
    370 ms to write and 105–120 ms to read, against 210 and 56 ms with 2 threads
    on this project's 2-core host (one-off timing). Each block is compressed on its own,
    so the file's bytes are the same whatever the count. A count someone already
    set (a host application, a test) is left as it is.

    Returns
    -------
    int, OpenEXR's global thread count after the call
    """
    if OpenEXR.global_thread_count() == 0:
        try:
            cores = len(os.sched_getaffinity(0))
        except (AttributeError, OSError):  # not on Linux
            cores = os.cpu_count() or 1
        if cores > 1:
            OpenEXR.set_global_thread_count(cores)
    return OpenEXR.global_thread_count()


# -- reading EXR files ----------------------------------------------------------------
def _open_exr(path: Path) -> OpenEXR.File:
    """Read every part and channel of ``path`` or raise PassError."""
    name = os.fspath(path)
    use_threads()
    if not path.exists():
        raise PassError(f"{name}: no such file")
    if not path.is_file():
        raise PassError(f"{name}: not a file")
    try:
        with open(path, "rb") as stream:
            magic = stream.read(4)
    except OSError as exc:
        raise PassError(f"{name}: cannot be read ({exc.strerror or exc})") from None
    if magic != _EXR_MAGIC:
        raise PassError(f"{name}: not a readable OpenEXR file (no OpenEXR signature)")
    # The bindings drop parts whose pixels fail to decode and only print a
    # warning, so compare against the header count and capture the warning.
    captured = io.StringIO()
    try:
        with contextlib.redirect_stdout(captured):
            expected = len(OpenEXR.File(name, header_only=True).parts)
            exr = OpenEXR.File(name, separate_channels=True)
            n_parts = len(exr.parts)
    except (RuntimeError, ValueError, OSError) as exc:
        raise PassError(
            f"{name}: not a readable OpenEXR file (truncated or corrupt: {exc})"
        ) from None
    warning = captured.getvalue().strip()
    if n_parts != expected or n_parts == 0 or warning:
        detail = _decode_failures(warning) or f"{n_parts} of {expected} parts decoded"
        raise PassError(f"{name}: not a readable OpenEXR file (truncated or corrupt: {detail})")
    return exr


@contextlib.contextmanager
def quiet_native_stderr():
    """Hold back what native code prints on file descriptor 2 inside the block.

    The OpenEXR C library prints one diagnostic line per damaged chunk of a
    truncated file before the Python bindings raise; the PassError raised
    for it already says what is wrong, so on error the lines are dropped
    (one clear message). When the block succeeds they are passed on.
    """
    fd = 2  # where C's stderr writes, whatever sys.stderr is
    try:
        sys.stderr.flush()
        saved = os.dup(fd)
    except (AttributeError, OSError, ValueError):  # no file descriptor 2 (some GUI hosts)
        yield
        return
    failed = False
    try:
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), fd)
            try:
                yield
            except BaseException:
                failed = True
                raise
            finally:
                os.dup2(saved, fd)
                if not failed:
                    sink.seek(0)
                    held = sink.read().decode("utf-8", "replace")
                    if held:
                        sys.stderr.write(held)
    finally:
        os.close(saved)


def _decode_failures(warning: str) -> str:
    """One line from the bindings' "Exception raised reading pixel data" warnings."""
    lines = [line.strip() for line in warning.splitlines() if line.strip()]
    pattern = re.compile(r"reading pixel data for part (\d+) - (.*)$")
    out = []
    for line in lines:
        match = pattern.search(line)
        out.append(f"part {match.group(1)}: {match.group(2)}" if match else line)
    return "; ".join(dict.fromkeys(out))


def _pixels(channel: OpenEXR.Channel) -> np.ndarray:
    return np.asarray(channel.pixels).astype(np.float32, copy=False)


def _all_channels(exr: OpenEXR.File) -> dict[str, np.ndarray]:
    """Full channel name -> (H, W) float32 over every part.

    Channels in a named part that carry no layer prefix (written by other
    tools) are prefixed with the part name, which is then their layer.
    """
    channels: dict[str, np.ndarray] = {}
    for part in exr.parts:
        part_name = part.header.get("name") if len(exr.parts) > 1 else None
        for key, channel in part.channels.items():
            full = f"{part_name}.{key}" if part_name and "." not in key else key
            channels[full] = _pixels(channel)
    return channels


def _split_pass(prefix: str) -> tuple[str, str] | None:
    """(layer, canonical pass) for a channel prefix naming a known pass."""
    for alias in _ALIASES_BY_LENGTH:
        if prefix == alias:
            return "", _ALIAS_TO_PASS[alias]
        if prefix.endswith("." + alias):
            return prefix[: -len(alias) - 1], _ALIAS_TO_PASS[alias]
    return None


@dataclass
class _Layer:
    """Passes of one view layer: canonical name -> channel -> pixels."""

    name: str
    passes: dict[str, dict[str, np.ndarray]]
    raw_names: list[str]


def _layers(channels: Mapping[str, np.ndarray]) -> dict[str, _Layer]:
    layers: dict[str, _Layer] = {}
    for full, pixels in channels.items():
        prefix, _, component = full.rpartition(".")
        found = _split_pass(prefix)
        if found is None:
            continue
        layer, pass_name = found
        entry = layers.setdefault(layer, _Layer(layer, {}, []))
        entry.passes.setdefault(pass_name, {})[component] = pixels
    # Every pass name under a detected layer, known or not, for messages.
    for layer in layers.values():
        head = f"{layer.name}." if layer.name else ""
        names = {
            full.rpartition(".")[0][len(head) :]
            for full in channels
            if full.startswith(head) and "." in full[len(head) :]
        }
        layer.raw_names = sorted(names)
    return layers


def _pick_layer(path: Path, channels: Mapping[str, np.ndarray], wanted: str | None) -> _Layer:
    name = os.fspath(path)
    layers = _layers(channels)
    if not layers:
        found = sorted({full.rpartition(".")[0] or full for full in channels})
        raise PassError(
            f"{name}: missing passes {_quoted(REQUIRED_PASSES)} "
            f"(found: {', '.join(found) or 'no channels'}); render with the cvsss pass setup"
        )
    if wanted is not None and wanted in layers:
        return layers[wanted]
    if len(layers) == 1:
        return next(iter(layers.values()))

    def score(layer: _Layer) -> int:
        return sum(p in layer.passes for p in REQUIRED_PASSES)

    ranked = sorted(layers.values(), key=score, reverse=True)
    if score(ranked[0]) > score(ranked[1]):
        return ranked[0]
    names = ", ".join(repr(layer.name) for layer in ranked)
    hint = f"the sidecar names {wanted!r}" if wanted else "the sidecar names none"
    raise PassError(f"{name}: several view layers ({names}) and {hint}; set 'view_layer'")


def _quoted(names: tuple[str, ...] | list[str]) -> str:
    return ", ".join(f"'{n}'" for n in names)


def _pass_array(path: Path, layer: _Layer, pass_name: str) -> np.ndarray:
    """(H, W) or (H, W, C) float32 stack of a pass's channels."""
    comps = layer.passes[pass_name]
    want = _PASS_CHANNELS[pass_name]
    if len({a.shape for a in comps.values()}) > 1:
        sizes = ", ".join(f"{c} {a.shape[1]}x{a.shape[0]}" for c, a in sorted(comps.items()))
        raise PassError(
            f"{os.fspath(path)}: channels of pass '{pass_name}' differ in size ({sizes})"
        )
    if len(want) == 1 and want[0] not in comps and len(comps) == 1:
        return next(iter(comps.values()))
    missing = [c for c in want if c not in comps]
    if missing:
        raise PassError(
            f"{os.fspath(path)}: pass '{pass_name}' lacks channel(s) {', '.join(missing)} "
            f"(found: {', '.join(sorted(comps))})"
        )
    if len(want) == 1:
        return comps[want[0]]
    return np.stack([comps[c] for c in want], axis=-1)


def _check_sizes(path: Path, arrays: Mapping[str, np.ndarray]) -> tuple[int, int]:
    sizes = {name: a.shape[:2] for name, a in arrays.items()}
    if len(set(sizes.values())) > 1:
        listing = ", ".join(f"{n} {w}x{h}" for n, (h, w) in sizes.items())
        raise PassError(f"{os.fspath(path)}: passes differ in size ({listing})")
    return next(iter(sizes.values()))


# -- public readers ---------------------------------------------------------------------
def read_channels(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every channel of an EXR: full name (``ViewLayer.Combined.A``) -> (H, W) float32,
    top row first. For a caller that reads more of a pass file than :func:`read_frame`
    does, so the file is decoded once (pass the result to it as ``channels``).

    Raises
    ------
    PassError
        As :func:`read_frame`, for a missing, unreadable, truncated or corrupt file.
    """
    return _all_channels(_open_exr(Path(path)))


def read_frame(
    path: str | os.PathLike,
    number: int | None = None,
    channels: Mapping[str, np.ndarray] | None = None,
) -> Frame:
    """Read a Blender pass EXR and its sidecar JSON into a :class:`Frame`.

    Parameters
    ----------
    path : str or PathLike
        The pass EXR; the sidecar is ``path.with_suffix(".json")``.
    number : int, optional
        Frame number; defaults to the sidecar's ``frame``, then to the file
        stem when it is numeric (``0012.exr`` -> 12).
    channels : mapping, optional
        The file's channels as :func:`read_channels` gave them (the file is then
        not read again).

    Returns
    -------
    Frame
        ``lighting`` = Diffuse Direct + Diffuse Indirect (Indirect is optional
        and counts as 0 when absent), ``albedo`` = Diffuse Color,
        ``combined`` = Combined RGB, ``depth`` = Depth (background 1e10 ->
        inf), ``material`` = Material Index, ``motion`` from Vector when
        present (:func:`motion_from_vector`), else None; ``sss_weight`` from the
        value AOV ``cvsss_weight`` on the pixels of materials whose sidecar
        entry says ``"weight_linked": true`` (NaN elsewhere), else None;
        ``indirect`` = Diffuse Indirect when present, else None;
        ``objects`` = Object Index when present, else None. A Material Index
        past the sidecar's slots (a thin object's copy, numbered apart for the
        user's own pass) reads as 0. Where the value
        AOV ``cvsss_thin`` (thin points, whose subsurface Cycles rendered) is at
        least :data:`THIN_PIXEL_SHARE`, ``material`` is 0: the post leaves those
        pixels as rendered. The
        frame also gets an attribute ``lighting_passes``: the tuple of passes
        summed into B. float16 channels are read as float32.

    Raises
    ------
    PassError
        The EXR is missing, not an OpenEXR file, truncated or corrupt, lacks
        a required pass (the message lists the passes found), has passes of
        different sizes, or the sidecar is missing/invalid/does not match.
    """
    path = Path(path)
    name = os.fspath(path)
    if number is not None and (
        isinstance(number, bool) or not isinstance(number, int | np.integer)
    ):
        raise TypeError(f"number must be an integer, got {number!r}")
    if channels is None:
        channels = _all_channels(_open_exr(path))
    sidecar = read_sidecar(path.with_suffix(".json"), exr_path=path)
    layer = _pick_layer(path, channels, sidecar.view_layer)

    missing = [p for p in REQUIRED_PASSES if p not in layer.passes]
    if missing:
        noun, it = ("pass", "it") if len(missing) == 1 else ("passes", "them")
        raise PassError(
            f"{name}: missing {noun} {_quoted(missing)} "
            f"(found: {', '.join(layer.raw_names) or 'none'}); "
            f"enable {it} in View Layer Properties > Passes"
        )
    arrays = {p: _pass_array(path, layer, p) for p in _PASS_CHANNELS if p in layer.passes}
    height, width = _check_sizes(path, arrays)
    cam = sidecar.camera
    if (cam.height, cam.width) != (height, width):
        raise PassError(
            f"{os.fspath(path.with_suffix('.json'))}: camera resolution {cam.width}x{cam.height} "
            f"does not match the passes in {name} ({width}x{height})"
        )

    lighting_passes = ["Diffuse Direct"]
    lighting = arrays["Diffuse Direct"].copy()
    if "Diffuse Indirect" in arrays:
        with np.errstate(over="ignore"):  # past float32: inf, repaired and counted below
            lighting += arrays["Diffuse Indirect"]
        lighting_passes.append("Diffuse Indirect")
    motion = motion_from_vector(arrays["Vector"]) if "Vector" in arrays else None
    sss_weight = None
    linked = [s for s, spec in sidecar.materials.items() if spec.options.get("weight_linked")]
    if linked and "SSS Weight" in arrays:
        # Per pixel only on the materials whose weight is linked; NaN (the
        # material's constant weight) elsewhere.
        on = np.isin(np.rint(np.nan_to_num(arrays["Material Index"])), linked)
        sss_weight = np.where(on, arrays["SSS Weight"], np.nan).astype(np.float32)
    material = arrays["Material Index"]
    top = max(sidecar.materials, default=0)
    if material.size and np.nanmax(material) > top + 0.5:
        # Numbers past the sidecar's table are materials that take no part (the copies
        # the pass render gives thin objects, numbered apart for the user's own
        # Material Index pass).
        material = np.where(material > top + 0.5, 0, material)
    if "Thin Points" in arrays:
        # Applied on reading rather than rewritten into the file after the render,
        # which would write every pass file twice.
        material = np.where(arrays["Thin Points"] >= THIN_PIXEL_SHARE, 0, material)

    if number is None:
        number = sidecar.frame
    if number is None:
        if not path.stem.isdigit():
            raise PassError(
                f"{name}: no frame number (not in the sidecar and the file name is not numeric)"
            )
        number = int(path.stem)
    try:
        frame = Frame(
            number=int(number),
            lighting=lighting,
            albedo=arrays["Diffuse Color"],
            combined=arrays["Combined"],
            depth=arrays["Depth"],
            material=material,
            camera=cam,
            materials=sidecar.materials,
            motion=motion,
            source=name,
            sss_weight=sss_weight,
            indirect=arrays.get("Diffuse Indirect"),
            objects=arrays.get("Object Index"),
        )
    except ValueError as exc:
        raise PassError(f"{name}: {exc}") from None
    frame.lighting_passes = tuple(lighting_passes)
    return frame


def read_pass(path: str | os.PathLike, name: str) -> np.ndarray:
    """One pass of a Blender multilayer EXR, by its name or any name it has had.

    Parameters
    ----------
    path : str or PathLike, a multilayer EXR with one view layer holding the pass
        (the view layer is detected; no sidecar needed)
    name : str, a pass this module knows, e.g. ``"Combined"`` or ``"Object Index"``
        (Blender's older names, ``"IndexOB"``, are found too)

    Returns
    -------
    (H, W) float32 for a one-channel pass (``Object Index``: the objects' Pass
    Index, whole numbers), else (H, W, C) in the pass's channel order (RGB
    linear for ``Combined``); EXR row order (top row first).

    Raises
    ------
    PassError
        Missing, not an EXR, truncated, without the pass, or the pass in
        several view layers.
    KeyError
        ``name`` is not a pass this module knows (a caller's mistake).
    """
    path = Path(path)
    name = _ALIAS_TO_PASS[name]
    channels = _all_channels(_open_exr(path))
    layers = [layer for layer in _layers(channels).values() if name in layer.passes]
    if len(layers) != 1:
        found = f"no {name} pass" if not layers else f"{name} pass in several view layers"
        raise PassError(f"{os.fspath(path)}: {found}")
    return _pass_array(path, layers[0], name).astype(np.float32)


def read_combined(path: str | os.PathLike) -> np.ndarray:
    """The Combined pass (RGB, linear) of a Blender EXR, e.g. a ground-truth render.

    Parameters
    ----------
    path : str or PathLike, a multilayer EXR holding a ``Combined`` pass (the
        view layer is detected; no sidecar needed)

    Returns
    -------
    (H, W, 3) float32, EXR row order.

    Raises
    ------
    PassError
        Missing, not an EXR, truncated, or without a Combined pass.
    """
    return read_pass(path, "Combined")


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """The RGB (linear) of a render Blender wrote as OpenEXR: single-layer or multilayer.

    Parameters
    ----------
    path : str or PathLike; an EXR with ``R``, ``G``, ``B`` channels (Blender's
        OpenEXR format) or one view layer's ``Combined`` pass (OpenEXR MultiLayer)

    Returns
    -------
    (H, W, 3) float32, EXR row order (top row first).

    Raises
    ------
    PassError
        Missing, not an EXR, truncated, or neither layout.
    """
    path = Path(path)
    channels = _all_channels(_open_exr(path))
    if all(c in channels for c in "RGB"):
        return np.stack([channels[c] for c in "RGB"], axis=-1).astype(np.float32)
    return read_combined(path)


def read_result(path: str | os.PathLike) -> dict:
    """Read a result EXR written by :func:`write_result` (or any layered EXR).

    Parameters
    ----------
    path : str or PathLike

    Returns
    -------
    dict
        Layer name -> array: (H, W, 3) float32 for R/G/B layers (Composite,
        SSS, Gamma), (H, W) float32 for single-channel layers (SampleCount,
        Alpha, Variance, ValidHistory and Mask as 0/1); other layers stack
        their channels in sorted order. Key ``"header"`` holds the string
        attributes of the header, e.g. ``"cvsss.method"``.

    Raises
    ------
    PassError
        Missing, non-EXR, truncated or corrupt file.
    """
    path = Path(path)
    exr = _open_exr(path)
    layers: dict[str, dict[str, np.ndarray]] = {}
    header: dict[str, str] = {}
    for part in exr.parts:
        for key, value in part.header.items():
            if isinstance(value, str):
                header.setdefault(key, value)
        for key, channel in part.channels.items():
            layer, _, comp = key.rpartition(".")
            layers.setdefault(layer, {})[comp] = _pixels(channel)
    out: dict = {}
    for layer, comps in layers.items():
        if set(comps) == {"R", "G", "B"}:
            out[layer] = np.stack([comps[c] for c in "RGB"], axis=-1)
        elif set(comps) == {"R", "G", "B", "A"}:
            out[layer] = np.stack([comps[c] for c in "RGBA"], axis=-1)
        elif len(comps) == 1:
            out[layer] = next(iter(comps.values()))
        else:
            out[layer] = np.stack([comps[c] for c in sorted(comps)], axis=-1)
    out["header"] = header
    return out


def list_frames(directory: str | os.PathLike) -> list[tuple[int, Path]]:
    """Pass EXRs named ``<digits>.exr`` in a folder, in frame order.

    Parameters
    ----------
    directory : str or PathLike

    Returns
    -------
    list of (int, Path)
        Frame number and file, sorted by number.

    Raises
    ------
    PassError
        The folder does not exist, is not a folder, holds no frame files, or
        holds two files for the same frame number (``1.exr`` and ``0001.exr``).
    """
    directory = Path(directory)
    name = os.fspath(directory)
    if not directory.exists():
        raise PassError(f"{name}: no such folder")
    if not directory.is_dir():
        raise PassError(f"{name}: not a folder")
    frames: dict[int, Path] = {}
    try:
        entries = sorted(directory.iterdir())
    except OSError as exc:
        raise PassError(f"{name}: cannot list folder ({exc.strerror or exc})") from None
    for entry in entries:
        match = _FRAME_NAME.match(entry.name)
        if match is None:
            continue
        try:
            is_file = entry.is_file()
        except OSError as exc:  # listed but not entered (a folder without its x bit)
            raise PassError(f"{name}: cannot open {entry.name} ({exc.strerror or exc})") from None
        if not is_file:
            continue
        number = int(match.group(1))
        if number in frames:
            raise PassError(
                f"{name}: frame {number} appears twice ({frames[number].name}, {entry.name})"
            )
        frames[number] = entry
    if not frames:
        raise PassError(f"{name}: no frame files named <digits>.exr (e.g. 0001.exr)")
    return sorted(frames.items())


# -- writers ------------------------------------------------------------------------------
def _as_output(path: str | os.PathLike) -> Path:
    path = Path(path)
    if path.suffix.lower() != ".exr":
        raise ValueError(f"output file must end in .exr, got {os.fspath(path)!r}")
    return path


def _encode(array: np.ndarray, half: bool) -> np.ndarray:
    a = np.ascontiguousarray(array, dtype=np.float32)
    if not half:
        return a
    # Values beyond the half range become ±inf, which is what EXR readers expect.
    with np.errstate(over="ignore"):
        return a.astype(np.float16)


def _header(**extra: str) -> dict:
    return {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **extra}


def write_passes(
    path: str | os.PathLike,
    frame: Frame,
    overwrite: bool = False,
    half: bool = False,
) -> None:
    """Write a Frame as a Blender-5-style pass EXR plus its sidecar JSON.

    One part per pass under view layer ``ViewLayer``: Combined (RGB, A = 1),
    Depth (Z; background written as 1e10), Material Index (X, as float),
    Object Index (X, when ``frame.objects`` is set),
    Diffuse Direct and Indirect (``frame.lighting`` split by ``frame.indirect``;
    all direct when it is None),
    Diffuse Color (= ``frame.albedo``) and, when ``frame.motion`` is set,
    Vector (:func:`vector_from_motion`). :func:`read_frame` gives the frame
    back. The sidecar (``path.with_suffix(".json")``) is written first so a
    pass EXR never appears without it.

    Parameters
    ----------
    path : str or PathLike
        Output ``.exr`` file; missing parent folders are created.
    frame : Frame
    overwrite : bool
        Replace existing files; otherwise raise FileExistsError.
    half : bool
        Store channels as 16-bit HALF instead of 32-bit FLOAT (background
        depth then reads back as inf).

    Raises
    ------
    FileExistsError
        The EXR or its sidecar exists and ``overwrite`` is false.
    OutputError
        The files cannot be written; nothing is left under either name.
    """
    path = _as_output(path)
    if not isinstance(frame, Frame):
        raise TypeError(f"frame must be a Frame, got {type(frame).__name__}")
    height, width = frame.shape
    depth = np.where(np.isfinite(frame.depth), frame.depth, BACKGROUND_DEPTH_WRITTEN)
    passes: dict[str, dict[str, np.ndarray]] = {
        "Combined": {
            **{c: frame.combined[..., i] for i, c in enumerate("RGB")},
            "A": np.ones((height, width), np.float32),
        },
        "Depth": {"Z": depth},
    }
    if frame.motion is not None:
        vector = vector_from_motion(frame.motion)
        passes["Vector"] = {c: vector[..., i] for i, c in enumerate("XYZW")}
    passes["Material Index"] = {"X": frame.material.astype(np.float32)}
    if frame.objects is not None:
        passes["Object Index"] = {"X": frame.objects.astype(np.float32)}
    if frame.indirect is None:
        direct, indirect = frame.lighting, np.zeros_like(frame.lighting)
    else:
        indirect = np.minimum(frame.indirect, frame.lighting)
        direct = frame.lighting - indirect
    passes["Diffuse Direct"] = {c: direct[..., i] for i, c in enumerate("RGB")}
    passes["Diffuse Indirect"] = {c: indirect[..., i] for i, c in enumerate("RGB")}
    passes["Diffuse Color"] = {c: frame.albedo[..., i] for i, c in enumerate("RGB")}

    parts = []
    for pass_name, comps in passes.items():
        part_name = f"{DEFAULT_VIEW_LAYER}.{pass_name}"
        extra = {"Software": "cvsss", "Frame": f"{frame.number:03d}"} if not parts else {}
        channels = {f"{part_name}.{c}": _encode(a, half) for c, a in comps.items()}
        parts.append(OpenEXR.Part(_header(**extra), channels, part_name))
    use_threads()
    exr = OpenEXR.File(parts)

    sidecar = make_sidecar(
        frame.camera,
        frame.materials,
        frame=frame.number,
        view_layer=DEFAULT_VIEW_LAYER,
        engine="SYNTHETIC",
    )
    text = (json.dumps(sidecar, indent=2) + "\n").encode("utf-8")
    if not overwrite:
        for target in (path, path.with_suffix(".json")):
            if target.exists():
                raise exists_error(target)
    # The sidecar goes first so a pass EXR never appears without it.
    write_files([(path.with_suffix(".json"), text), (path, exr)], overwrite)


def _result_array(result: FrameResult, field: str, shape: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(getattr(result, field))
    if a.shape != shape:
        raise ValueError(f"result {field} has shape {a.shape}, expected {shape}")
    return a.astype(np.float32)


def write_result(
    path: str | os.PathLike,
    result: FrameResult,
    overwrite: bool = False,
    metadata: Mapping[str, object] | None = None,
) -> None:
    """Write a processed frame as a single-part layered EXR.

    Layers (FLOAT): ``Composite.R/G/B``, ``SSS.R/G/B``, ``Gamma.R/G/B``,
    ``SampleCount.V``, ``Alpha.V``, ``Variance.V``, ``ValidHistory.V`` and
    ``Mask.V`` (0/1). Header string attributes: ``cvsss.method``,
    ``cvsss.frame``, the scalar statistics of the result (``cvsss.spp``,
    ``cvsss.samples``, ``cvsss.sampling_ms``, ``cvsss.update_ms``,
    ``cvsss.total_ms``, ``cvsss.distant_share``, ``cvsss.fallback_share``,
    ``cvsss.repaired``) and ``cvsss.<key>`` = ``str(value)`` per metadata item.

    Parameters
    ----------
    path : str or PathLike
        Output ``.exr`` file; missing parent folders are created.
    result : FrameResult
    overwrite : bool
        Replace an existing file; otherwise raise FileExistsError.
    metadata : mapping str -> object, optional
        Extra header entries (e.g. parameters); keys must be non-empty
        strings without whitespace and not one of the names above.

    Raises
    ------
    FileExistsError
        The file exists and ``overwrite`` is false.
    OutputError
        The file cannot be written; nothing is left under its name.
    """
    path = _as_output(path)
    if not isinstance(result, FrameResult):
        raise TypeError(f"result must be a FrameResult, got {type(result).__name__}")
    shape = np.shape(result.composite)[:2]
    if len(shape) != 2:
        raise ValueError(
            f"result composite must be (H, W, 3), got shape {np.shape(result.composite)}"
        )
    header = _header(**{"cvsss.method": str(result.method), "cvsss.frame": str(int(result.number))})
    for stat in _RESULT_STATS:
        value = getattr(result, stat)
        header[f"cvsss.{stat}"] = repr(value.item() if isinstance(value, np.generic) else value)
    for key, value in (metadata or {}).items():
        if not isinstance(key, str) or not key or any(ch.isspace() for ch in key):
            raise ValueError(f"metadata keys must be non-empty strings without spaces, got {key!r}")
        if key in _RESERVED_KEYS:
            raise ValueError(f"metadata key {key!r} is reserved (one of {sorted(_RESERVED_KEYS)})")
        header[f"cvsss.{key}"] = str(value)
    channels: dict[str, np.ndarray] = {}
    for layer, (field, comps) in _RESULT_LAYERS.items():
        want = (*shape, 3) if len(comps) == 3 else shape
        array = _result_array(result, field, want)
        if len(comps) == 1:
            channels[f"{layer}.V"] = np.ascontiguousarray(array)
        else:
            for i, c in enumerate(comps):
                channels[f"{layer}.{c}"] = np.ascontiguousarray(array[..., i])
    use_threads()
    write_files([(path, OpenEXR.File(header, channels))], overwrite)
