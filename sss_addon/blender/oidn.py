"""OpenImageDenoise, called directly: the library Blender itself ships and loads.

Blender's compositor Denoise node makes a new OIDN device and new filters
for every image, and building a filter (OIDN's ``commit``: the network and
its weights laid out for the image size) costs about as much as running it.
Apply on Render denoises one finished frame after another at the same size,
so :class:`Filters` builds the device and its filters once and runs them on
each frame (the time saved: docs/performance.md, *Apply on Render*).

:class:`Filters` does what the node does (Blender 5.0's
``node_composite_denoise.cc`` and ``denoised_auxiliary_pass.cc``), so its
output is the node's bit for bit (tests/blender/test_oidn.py), and the node
gives Cycles' own denoised Combined bit for bit:

- the "RT" filter, ``hdr`` on, the quality asked for;
- prefilter *Accurate*: the albedo and the normal are first denoised on their
  own (a filter each, in place, same quality), and the main filter takes them
  as clean (``cleanAux``); *None*: taken as clean as they are; *Fast*: taken
  as noisy (``cleanAux`` off), no prefilter;
- the normal guides the filter only together with the albedo;
- rows bottom-up, as Blender and Cycles store images: the network is not
  mirror-symmetric, so rows top-down would give other values.

Only the CPU device: a GPU device may not read host memory, and the shared
images here are NumPy arrays. :func:`library` is None where the library
cannot be found or is older than OIDN 2; callers then use the compositor.
"""

from __future__ import annotations

import ctypes
import sys
import weakref
from collections.abc import Iterator
from pathlib import Path

import numpy as np

#: The library's file name per platform, as Blender ships it.
LIBRARY_NAMES = {
    "linux": "libOpenImageDenoise.so.2",
    "win32": "OpenImageDenoise.dll",
    "darwin": "libOpenImageDenoise.2.dylib",
}
#: OIDN_DEVICE_TYPE_CPU, OIDN_FORMAT_FLOAT3 (oidn.h).
DEVICE_CPU, FORMAT_FLOAT3 = 1, 3
#: Cycles' and the node's quality -> OIDNQuality (oidn.h; FAST from OIDN 2.3).
QUALITY = {"HIGH": 6, "BALANCED": 5, "FAST": 4}
#: The first OIDN version whose filters take a quality (``version`` is 10000·major + …).
MIN_VERSION = 20000
#: The first with the FAST quality; the node asks for HIGH on older ones.
FAST_VERSION = 20300

_handle = ctypes.c_void_p
_SIGNATURES = {
    "oidnNewDevice": (_handle, [ctypes.c_int]),
    "oidnCommitDevice": (None, [_handle]),
    "oidnReleaseDevice": (None, [_handle]),
    "oidnGetDeviceInt": (ctypes.c_int, [_handle, ctypes.c_char_p]),
    "oidnGetDeviceError": (ctypes.c_int, [_handle, ctypes.POINTER(ctypes.c_char_p)]),
    "oidnNewFilter": (_handle, [_handle, ctypes.c_char_p]),
    "oidnSetSharedFilterImage": (
        None,
        [_handle, ctypes.c_char_p, ctypes.c_void_p, ctypes.c_int]
        + [ctypes.c_size_t] * 5,  # width, height, byte offset, pixel and row strides
    ),
    "oidnSetFilterBool": (None, [_handle, ctypes.c_char_p, ctypes.c_bool]),
    "oidnSetFilterInt": (None, [_handle, ctypes.c_char_p, ctypes.c_int]),
    "oidnCommitFilter": (None, [_handle]),
    "oidnExecuteFilter": (None, [_handle]),
    "oidnReleaseFilter": (None, [_handle]),
}

_library: ctypes.CDLL | None = None
_version = 0  # the library's OIDN version (10000·major + 100·minor + patch)
_searched = False


class OidnError(RuntimeError):
    """OIDN reported an error (its own message)."""


def _candidates() -> Iterator[str]:
    """Where Blender keeps the library: loaded already (the bare name finds it), else next
    to Blender's binary (Linux ``lib``, Windows ``blender.shared``, macOS ``Resources/lib``)."""
    name = LIBRARY_NAMES.get(sys.platform, LIBRARY_NAMES["linux"])
    yield name
    try:
        import bpy

        binary = Path(bpy.app.binary_path)
    except (ImportError, AttributeError, TypeError):
        return
    for folder in ("lib", "blender.shared", "../Resources/lib"):
        yield str(binary.parent / folder / name)


def library() -> ctypes.CDLL | None:
    """The OIDN library Blender ships, its functions typed; None where it is missing or
    older than OIDN 2 (looked up once)."""
    global _library, _version, _searched
    if _searched:
        return _library
    _searched = True
    for candidate in _candidates():
        try:
            lib = ctypes.CDLL(candidate)
            for function, (result, arguments) in _SIGNATURES.items():
                getattr(lib, function).restype = result
                getattr(lib, function).argtypes = arguments
        except (OSError, AttributeError):
            continue
        device = lib.oidnNewDevice(DEVICE_CPU)
        if not device:
            continue
        version = lib.oidnGetDeviceInt(device, b"version")
        lib.oidnReleaseDevice(device)
        if version >= MIN_VERSION:
            _library, _version = lib, version
            break
    return _library


def _release(lib: ctypes.CDLL, device: int, filters: list[int]) -> None:
    for handle in filters:
        lib.oidnReleaseFilter(handle)
    lib.oidnReleaseDevice(device)


class Filters:
    """A CPU device and the filters of one prefilter, quality and guide set, built for one
    image size and run on one image after another.

    Parameters
    ----------
    prefilter : {"NONE", "FAST", "ACCURATE"}
    quality : {"HIGH", "BALANCED", "FAST"}
    albedo, normal : bool
        The guides given to :meth:`run` (the normal only with the albedo).

    Raises
    ------
    OidnError
        No OIDN library (:func:`library` is None) or the device failed.

    Notes
    -----
    The device and filters are released by :meth:`close`, or when the object is
    collected. At 1920×1080 the images held here take about 100 MB, and OIDN's own
    scratch memory more: keep one for a render, not for the session of Blender.
    """

    def __init__(self, prefilter: str, quality: str, albedo: bool, normal: bool) -> None:
        lib = library()
        if lib is None:
            raise OidnError("Blender's OpenImageDenoise library was not found")
        self.lib = lib
        self.prefilter = prefilter
        self.albedo, self.normal = albedo, albedo and normal
        self.device = lib.oidnNewDevice(DEVICE_CPU)
        self.filters: list[int] = []  # in the order run: the guides' prefilters, then the main
        # Released with the object when close() is never called.
        self._finalizer = weakref.finalize(self, _release, lib, self.device, self.filters)
        lib.oidnCommitDevice(self.device)
        self._check()
        self.quality = QUALITY["HIGH" if quality == "FAST" and _version < FAST_VERSION else quality]
        self.size: tuple[int, int] | None = None
        self.images: dict[str, np.ndarray] = {}

    def _check(self) -> None:
        message = ctypes.c_char_p()
        if self.lib.oidnGetDeviceError(self.device, ctypes.byref(message)):
            text = message.value.decode(errors="replace") if message.value else "unknown error"
            raise OidnError(f"OpenImageDenoise: {text}")

    def _filter(self, images: dict[str, str], **flags: bool) -> None:
        """A committed "RT" filter reading and writing the named buffers of :attr:`images`,
        run after those already in :attr:`filters`."""
        lib = self.lib
        handle = lib.oidnNewFilter(self.device, b"RT")
        self.filters.append(handle)
        for role, key in images.items():
            buffer = self.images[key]
            height, width = buffer.shape[:2]
            lib.oidnSetSharedFilterImage(
                handle, role.encode(), buffer.ctypes.data, FORMAT_FLOAT3,
                width, height, 0, buffer.strides[1], buffer.strides[0],
            )  # fmt: skip
        for name, value in flags.items():
            lib.oidnSetFilterBool(handle, name.encode(), value)
        lib.oidnSetFilterInt(handle, b"quality", self.quality)
        lib.oidnCommitFilter(handle)
        self._check()

    def _build(self, height: int, width: int) -> None:
        for handle in self.filters:
            self.lib.oidnReleaseFilter(handle)
        self.filters.clear()
        names = ["color", "output"] + ["albedo"] * self.albedo + ["normal"] * self.normal
        self.images = {key: np.zeros((height, width, 3), np.float32) for key in names}
        if self.prefilter == "ACCURATE":  # the guides' own filters run first
            for guide in ("albedo", "normal")[: self.albedo + self.normal]:
                self._filter({guide: guide, "output": guide})
        main = {key: key for key in names}
        self._filter(main, hdr=True, cleanAux=self.prefilter != "FAST")
        self.size = (height, width)

    def run(
        self,
        color: np.ndarray,
        albedo: np.ndarray | None = None,
        normal: np.ndarray | None = None,
    ) -> np.ndarray:
        """The denoised image.

        Parameters
        ----------
        color : (H, W, >=3) float, linear, top row first
            Only the first three channels are read.
        albedo, normal : (H, W, 3) float or None
            The raw guides (prefiltered here as the prefilter asks); given exactly
            when the object was made with them.

        Returns
        -------
        (H, W, 3) float32, top row first.
        """
        if not self._finalizer.alive:
            raise OidnError("the filters were closed")
        if (albedo is not None) != self.albedo or (normal is not None) != self.normal:
            raise ValueError("the guides given must be those the filters were built for")
        height, width = color.shape[:2]
        if self.size != (height, width):
            self._build(height, width)
        for key, pixels in (("color", color), ("albedo", albedo), ("normal", normal)):
            if pixels is not None:
                self.images[key][...] = pixels[::-1, :, :3]
        for handle in self.filters:
            self.lib.oidnExecuteFilter(handle)
            self._check()
        return self.images["output"][::-1].copy()

    def run_again(self, color: np.ndarray) -> np.ndarray:
        """The denoised ``color``, guided by the guides of the last :meth:`run`: only the
        main filter runs, on the guides as that run left them (prefiltered already).

        Bit for bit ``run(color, albedo, normal)`` with the last run's guides, for the
        cost of the main filter alone.

        Parameters
        ----------
        color : (H, W, >=3) float, linear, top row first, the last run's size

        Returns
        -------
        (H, W, 3) float32, top row first.
        """
        if not self._finalizer.alive:
            raise OidnError("the filters were closed")
        if self.size != tuple(color.shape[:2]):
            raise ValueError("run_again needs an image of the last run's size")
        self.images["color"][...] = color[::-1, :, :3]
        self.lib.oidnExecuteFilter(self.filters[-1])
        self._check()
        return self.images["output"][::-1].copy()

    def close(self) -> None:
        """Release the filters and the device (safe to call twice)."""
        self._finalizer()
        self.images = {}
        self.size = None
