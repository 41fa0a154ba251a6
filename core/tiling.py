"""The post-process split in space: image tiles with a halo, bit for bit (docs/explanation/design.md §12).

The post-process is sequential in time (each method carries a per-pixel
history from frame to frame) but local in space: a pixel's result at frame k
depends on the passes of frame k within the scattering radius and on the
history of frame k−1 where its motion vector points. So the image is cut into
tiles (their *cores*, a partition of the image), and each tile is processed on
a *window*: its core plus a halo of

    halo = ceil(max scattering radius, px) + ceil(max |motion|, px) + 1

pixels (clipped to the image), computed per frame from the passes, the camera
and the materials (:func:`halo_px`). Tile i at frame k reads the passes of
frame k on its window and the history of frame k−1 on its window, which the
cores of tile i and its neighbours at frame k−1 hold (reprojection crosses
tile borders). Only the core of the tile's result is kept.

Why the core pixels equal the whole-image run bit for bit:

- a cropped frame (:class:`core.frame.Crop`) keeps the image's camera, and its
  pixels keep their image coordinates, which seed the per-pixel hash and place
  every sample and tap in float32 exactly as the whole image does;
- a core pixel's samples land within ``ceil(radius)`` pixels of it, and the
  surface area at a landing pixel reads its neighbours (the ``+ 1``); the
  history it reprojects from lies within ``ceil(|motion|)``: all inside the
  window, where passes and history are those of the whole image; the
  random-walk energy at a pixel (core.energy) reads the depth two pixels
  away, within ``ceil(radius) + 1`` too, as any scattering slot has a radius
  above 0;
- a per-pixel rule that needs a frame-level yardstick (the temporal reuse's
  ε) takes the whole image's, computed once per frame and carried by the
  crop (:attr:`core.frame.Crop.light_scale`);
- the frame-level figures of a tile count its core pixels only, and the whole
  image's are formed from the assembled images or summed integers (spp is
  Σ samples / Σ SSS pixels, never a mean of tile means).

Splitting in *time* with a warm-up would not reproduce the run: with the
paper's η_cv = 1e-6 the control-variate covariance remembers ~10⁶ frames.

State
-----
Tiles exchange processor states (:meth:`core.methods.Processor.state`)
without knowing them: an array whose leading dimensions are the image's (or
the window's) is per-pixel and is cropped and assembled; any other array must
not depend on the image size (it is taken from the tiles, which must agree).
New per-pixel history buffers therefore tile without changes here.

Scheduling is not done here (core runs no threads or processes):
:class:`TiledProcessor` hands tile jobs to an :class:`Executor` — run inline
by :class:`InlineExecutor`, on a Dask cluster by the ``cvsss`` front-end.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from .frame import Crop, Frame, compact_slots, slot_keys
from .geometry import light_scale
from .method import Method, MethodOptions
from .methods import get_method, make_processor
from .params import SSSParams
from .profiles.base import Profile
from .profiles.factory import ProfileCache
from .profiles.radial import radial_model
from .result import FrameResult

#: Box (y0, y1, x0, x1) in image pixels, end exclusive.
Box = tuple[int, int, int, int]

#: Relative margin on the scattering radius: samples are placed in float32.
RADIUS_MARGIN = 1e-6


# -- the grid and the halo -------------------------------------------------------------------
def tile_cores(image: tuple[int, int], size: int) -> list[Box]:
    """Cores of the tiles of side ``size`` covering ``image`` (H, W), row by row.

    >>> tile_cores((3, 5), 2)
    [(0, 2, 0, 2), (0, 2, 2, 4), (0, 2, 4, 5), (2, 3, 0, 2), (2, 3, 2, 4), (2, 3, 4, 5)]
    """
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"tile size must be an integer >= 1, got {size!r}")
    h, w = image
    return [
        (y, min(y + size, h), x, min(x + size, w))
        for y in range(0, h, size)
        for x in range(0, w, size)
    ]


def window(core: Box, halo: int, image: tuple[int, int]) -> Box:
    """``core`` grown by ``halo`` pixels on every side, clipped to ``image`` (H, W)."""
    y0, y1, x0, x1 = core
    return (
        max(0, y0 - halo),
        min(image[0], y1 + halo),
        max(0, x0 - halo),
        min(image[1], x1 + halo),
    )


def _overlap(a: Box, b: Box) -> Box | None:
    y0, y1 = max(a[0], b[0]), min(a[1], b[1])
    x0, x1 = max(a[2], b[2]), min(a[3], b[3])
    return (y0, y1, x0, x1) if y0 < y1 and x0 < x1 else None


def neighbours(cores: Sequence[Box], box: Box) -> list[int]:
    """Indices of the cores that overlap ``box`` (whose history a window needs)."""
    return [i for i, c in enumerate(cores) if _overlap(c, box) is not None]


def scatter_radius_px(frame: Frame, profile: Profile) -> float:
    """Largest distance in pixels at which a sample or tap of ``frame`` can land.

    For each scattering material slot: its truncation radius (the largest over
    channels, scene units; the separable kernels span the same radius) over
    the smallest pixel footprint of its pixels (perspective: at their nearest
    depth). 0 without subsurface pixels.
    """
    slots = compact_slots(frame.material, slot_keys(frame.materials))
    n = profile.n_slots
    scatters = np.zeros(max(n, 1), dtype=bool)
    scatters[:n] = profile.scatters()
    finite = np.isfinite(frame.depth)
    best = 0.0
    for s in np.unique(slots[finite & (slots > 0) & (slots < n)]):
        if not scatters[s]:
            continue
        z = float(frame.depth[finite & (slots == s)].min())
        fw, fh = frame.camera.footprint(np.array(z))
        rmax = float(np.max(radial_model(profile, int(s)).rmax))
        best = max(best, rmax / float(min(fw, fh)))
    return best


def motion_px(frame: Frame) -> float:
    """Largest |motion| (pixels) of the pixels whose motion points inside the image.

    A vector pointing off the image drops the pixel's history in the whole
    image and in a tile alike, so it needs no halo.
    """
    if frame.motion is None:
        return 0.0
    h, w = frame.image_shape
    oy, ox = frame.origin
    fh, fw = frame.shape
    yy, xx = np.mgrid[oy : oy + fh, ox : ox + fw]
    mx = frame.motion[..., 0].astype(np.float64)
    my = frame.motion[..., 1].astype(np.float64)
    px = np.rint(xx + mx)
    py = np.rint(yy + my)
    inside = (px >= 0) & (px < w) & (py >= 0) & (py < h)
    if not inside.any():
        return 0.0
    return float(np.hypot(mx, my)[inside].max())


def halo_px(frame: Frame, profile: Profile) -> int:
    """The halo of ``frame``: ``ceil(radius px) + ceil(|motion| px) + 1`` (module doc).

    The radius carries a relative margin of :data:`RADIUS_MARGIN` because
    samples are placed in float32.
    """
    radius = scatter_radius_px(frame, profile) * (1.0 + RADIUS_MARGIN)
    return int(math.ceil(radius)) + int(math.ceil(motion_px(frame))) + 1


# -- cropping and assembling -----------------------------------------------------------------
def crop_frame(frame: Frame, box: Box, core: Box, light: np.ndarray | None = None) -> Frame:
    """The passes of ``frame`` (a whole image) on ``box``, answering for ``core``.

    The crop keeps the camera, the material table and the frame number; its
    ``repaired`` count is 0 (the whole frame's was counted when it was read).
    ``light`` (3,) is the whole image's :func:`core.geometry.light_scale`.
    """
    if frame.crop is not None:
        raise ValueError("crop_frame takes a whole frame, not a crop")
    y0, y1, x0, x1 = box

    return frame.map_pixels(
        lambda a: np.ascontiguousarray(a[y0:y1, x0:x1]),
        repaired=0,
        crop=Crop(
            image=frame.shape,
            origin=(y0, x0),
            core=tuple(core),
            light_scale=None if light is None else tuple(float(v) for v in light),
        ),
    )


def _is_pixels(array: np.ndarray, shape: tuple[int, int]) -> bool:
    return array.ndim >= 2 and array.shape[:2] == tuple(shape)


@dataclass
class StatePiece:
    """A processor state on one box of the image (module doc, State).

    Attributes
    ----------
    box : Box, image coordinates
    pixels : dict name -> (h, w, ...) array, the per-pixel arrays on ``box``
    other : dict name -> array, the arrays that do not depend on the image size
    """

    box: Box
    pixels: dict[str, np.ndarray]
    other: dict[str, np.ndarray]

    @property
    def shape(self) -> tuple[int, int]:
        return (self.box[1] - self.box[0], self.box[3] - self.box[2])


def split_state(state: Mapping[str, np.ndarray], box: Box) -> StatePiece:
    """The state of a processor that ran on ``box`` (a whole image or a window)."""
    shape = (box[1] - box[0], box[3] - box[2])
    pixels, other = {}, {}
    for key, value in state.items():
        a = np.asarray(value)
        (pixels if _is_pixels(a, shape) else other)[key] = a
    return StatePiece(tuple(box), pixels, other)


def crop_piece(piece: StatePiece, box: Box) -> StatePiece:
    """``piece`` restricted to ``box`` (which it must contain)."""
    y0, y1, x0, x1 = piece.box
    if not (y0 <= box[0] < box[1] <= y1 and x0 <= box[2] < box[3] <= x1):
        raise ValueError(f"box {box} is not inside the state's box {piece.box}")
    sy, sx = slice(box[0] - y0, box[1] - y0), slice(box[2] - x0, box[3] - x0)
    pixels = {k: np.ascontiguousarray(v[sy, sx]) for k, v in piece.pixels.items()}
    return StatePiece(tuple(box), pixels, dict(piece.other))


def join_pieces(pieces: Sequence[StatePiece], box: Box) -> dict[str, np.ndarray]:
    """The state on ``box`` from pieces that cover it (parts outside ``box`` are ignored).

    Raises
    ------
    ValueError
        The pieces hold different arrays, disagree on an array that does not
        depend on the image size, or leave part of ``box`` uncovered.
    """
    if not pieces:
        raise ValueError("no state pieces to join")
    first = pieces[0]
    shape = (box[1] - box[0], box[3] - box[2])
    for p in pieces[1:]:
        if p.pixels.keys() != first.pixels.keys() or p.other.keys() != first.other.keys():
            raise ValueError(
                f"state pieces hold different arrays: {sorted(first.pixels)} + "
                f"{sorted(first.other)} against {sorted(p.pixels)} + {sorted(p.other)}"
            )
        for k, v in p.other.items():
            ref = first.other[k]
            if v.dtype != ref.dtype or not np.array_equal(v, ref):
                raise ValueError(
                    f"state array {k!r} is neither per-pixel nor the same in every tile"
                )
    out = {k: np.empty((*shape, *v.shape[2:]), dtype=v.dtype) for k, v in first.pixels.items()}
    covered = np.zeros(shape, dtype=bool)
    for p in pieces:
        o = _overlap(p.box, box)
        if o is None:
            continue
        dst = (slice(o[0] - box[0], o[1] - box[0]), slice(o[2] - box[2], o[3] - box[2]))
        src = (slice(o[0] - p.box[0], o[1] - p.box[0]), slice(o[2] - p.box[2], o[3] - p.box[2]))
        for k, v in p.pixels.items():
            out[k][dst] = v[src]
        covered[dst] = True
    if out and not covered.all():
        raise ValueError(f"state pieces leave part of {box} uncovered")
    return {**out, **{k: v.copy() for k, v in first.other.items()}}


def crop_result(result: FrameResult, box: Box, core: Box) -> FrameResult:
    """The result of a window ``box`` restricted to ``core`` (images only; its
    frame-level figures already count the core only)."""
    shape = (box[1] - box[0], box[3] - box[2])
    sy = slice(core[0] - box[0], core[1] - box[0])
    sx = slice(core[2] - box[2], core[3] - box[2])
    changes = {}
    for f in dataclasses.fields(result):
        value = getattr(result, f.name)
        if isinstance(value, np.ndarray) and _is_pixels(value, shape):
            changes[f.name] = np.ascontiguousarray(value[sy, sx])
    return dataclasses.replace(result, **changes)


def assemble_result(
    pieces: Sequence[tuple[Box, FrameResult]],
    image: tuple[int, int],
    *,
    repaired: int = 0,
    total_ms: float = 0.0,
) -> FrameResult:
    """The whole image's FrameResult from the core results of its tiles.

    Images are pasted; spp is the mean count over the assembled SSS mask
    (Σ samples / Σ pixels, exactly the whole-image figure), the shares are
    quotients of summed integers, ``sampling_ms`` and ``update_ms`` the summed work
    of the tiles (not wall time), ``total_ms`` and ``repaired`` as given.
    """
    if not pieces:
        raise ValueError("no tile results to assemble")
    first = pieces[0][1]
    images = {}
    for f in dataclasses.fields(first):
        value = getattr(first, f.name)
        if isinstance(value, np.ndarray):
            images[f.name] = np.empty((*image, *value.shape[2:]), dtype=value.dtype)
    for core, res in pieces:
        if res.method != first.method or res.number != first.number:
            raise ValueError(
                f"tile results of {res.method} frame {res.number} and {first.method} frame "
                f"{first.number} cannot be assembled"
            )
        for name, out in images.items():
            out[core[0] : core[1], core[2] : core[3]] = getattr(res, name)
    counts, mask = images["counts"], images["mask"]
    pixels = int(np.count_nonzero(mask))
    samples = sum(r.samples for _, r in pieces)
    fallback = sum(r.fallback for _, r in pieces)
    draws = sum(r.draws for _, r in pieces)
    distant = sum(r.distant_pixels for _, r in pieces)
    return FrameResult(
        number=first.number,
        method=first.method,
        **images,
        spp=float(np.mean(counts[mask])) if pixels else 0.0,
        samples=int(samples),
        sampling_ms=float(sum(r.sampling_ms for _, r in pieces)),
        update_ms=float(sum(r.update_ms for _, r in pieces)),
        total_ms=float(total_ms),
        distant_share=distant / pixels if pixels else 0.0,
        fallback_share=fallback / draws if draws else 0.0,
        repaired=int(repaired),
        fallback=int(fallback),
        draws=int(draws),
        distant_pixels=int(distant),
    )


# -- one tile --------------------------------------------------------------------------------
@dataclass
class TileOutput:
    """What one tile of one frame returns: its core's result and state.

    Attributes
    ----------
    core : Box
    result : FrameResult on the core (frame-level figures of the core)
    state : StatePiece on the core (the history for the next frame)
    work_s, cpu_s : wall and CPU seconds of the tile's processing
    worker : process id that processed it
    """

    core: Box
    result: FrameResult
    state: StatePiece
    work_s: float = 0.0
    cpu_s: float = 0.0
    worker: int = 0

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays it carries (what a worker sends back)."""
        arrays = [v for v in vars(self.result).values() if isinstance(v, np.ndarray)]
        arrays += [*self.state.pixels.values(), *self.state.other.values()]
        return int(sum(a.nbytes for a in arrays))


def frame_nbytes(frame: Frame) -> int:
    """Bytes of a frame's pass arrays (what a tile's window costs to send)."""
    return int(sum(a.nbytes for a in vars(frame).values() if isinstance(a, np.ndarray)))


#: Processors reused by :func:`run_tile` in this process, per (method, params, options);
#: a processor is taken out while it works, so concurrent threads never share one.
_POOL: dict[tuple, list] = {}


def run_tile(
    name: str,
    params: SSSParams,
    options: MethodOptions,
    frame: Frame,
    history: Sequence[StatePiece],
) -> TileOutput:
    """Process one tile: ``frame`` (a crop, :func:`crop_frame`) with the history on its
    window assembled from ``history`` (the previous frame's pieces of the tile and
    its neighbours; empty: no history yet).

    A pure function of its arguments (the processor it borrows is fully reset
    by ``restore``), so a tile can run anywhere and again.
    """
    crop = frame.crop
    if crop is None:
        raise ValueError("run_tile needs a cropped frame (crop_frame)")
    oy, ox = crop.origin
    box = (oy, oy + frame.shape[0], ox, ox + frame.shape[1])
    state = join_pieces(history, box) if history else {}
    key = (name, params, options)
    pool = _POOL.setdefault(key, [])
    try:
        processor = pool.pop()
    except IndexError:
        processor = make_processor(name, params, options)
    began, cpu = time.perf_counter(), time.process_time()
    try:
        processor.restore(state)
        result = processor.process(frame)
        piece = split_state(processor.state(), box)
    finally:
        pool.append(processor)
    return TileOutput(
        tuple(crop.core),
        crop_result(result, box, crop.core),
        crop_piece(piece, crop.core),
        time.perf_counter() - began,
        time.process_time() - cpu,
        os.getpid(),
    )


# -- the tiled processor ---------------------------------------------------------------------
class Executor(Protocol):
    """Where tile jobs run (the Dask ``Client`` API, reduced to what tiling uses).

    ``submit(fn, *args)`` returns a handle; handles may be passed as arguments
    (also inside lists) to later jobs, which receive their values.
    ``scatter(value)`` makes a handle of a value. ``gather(handles)`` returns
    their values, raising one of ``lost`` when work was lost (a worker died
    holding it): the tiled processor then submits the frame again.
    """

    lost: tuple[type[BaseException], ...]

    def submit(self, fn, *args) -> Any: ...

    def scatter(self, value: Any) -> Any: ...

    def gather(self, handles: list) -> list: ...


class InlineExecutor:
    """Runs each job when it is submitted, in this process (handles are the values)."""

    lost: tuple[type[BaseException], ...] = ()

    def submit(self, fn, *args):
        return fn(*args)

    def scatter(self, value):
        return value

    def gather(self, handles):
        return list(handles)


@dataclass
class FramePlan:
    """The tiles of one frame: halo, windows and the handles of the cropped passes."""

    number: int
    halo: int
    windows: list[Box]
    frames: list[Any]


class TileSession:
    """What the tiled processors of one run share: the grid, the executor, and per
    frame the halo and the cropped passes (scattered once for every method).

    Parameters
    ----------
    executor : Executor
    tile : int, tile side in pixels
    params, options : the run's (the profile that bounds the scattering radius)
    halo : int or None, force this halo (tests); None: :func:`halo_px` per frame
    log : printer of a line when a frame's lost work is submitted again, or None
    """

    def __init__(
        self,
        executor: Executor,
        tile: int,
        params: SSSParams,
        options: MethodOptions,
        halo: int | None = None,
        log=None,
    ) -> None:
        if isinstance(tile, bool) or not isinstance(tile, int) or tile < 1:
            raise ValueError(f"tile must be an integer >= 1, got {tile!r}")
        if halo is not None and (isinstance(halo, bool) or not isinstance(halo, int) or halo < 0):
            raise ValueError(f"halo must be an integer >= 0, got {halo!r}")
        self.executor = executor
        self.log = log
        self.tile = tile
        self.forced_halo = halo
        self.profiles = ProfileCache(params, options.profile)
        self.cores: list[Box] = []
        self.image: tuple[int, int] | None = None
        self._plan: FramePlan | None = None
        self.halos: dict[int, int] = {}
        #: Totals over the run (the bench's throughput model): frames planned, tiles
        #: processed, their work (s), window and image pixels, bytes of the windows'
        #: passes sent, bytes of tile outputs returned, client seconds outside waiting.
        self.stats = dict.fromkeys(
            (
                "frames",
                "tiles",
                "work_s",
                "window_px",
                "image_px",
                "bytes_passes",
                "bytes_out",
                "client_s",
                "cpu_s",
            ),
            0,
        )
        #: CPU seconds of tile work per worker process id.
        self.worker_cpu: dict[int, float] = {}

    def plan(self, frame: Frame, fresh: bool = False) -> FramePlan:
        """The tiles of ``frame`` (a whole image), cropped and scattered once."""
        if frame.crop is not None:
            raise ValueError("a tiled run takes whole frames")
        if self.image is None:
            self.image = frame.shape
            self.cores = tile_cores(frame.shape, self.tile)
        elif frame.shape != self.image:
            raise ValueError(
                f"frame {frame.number} is {frame.shape[1]}x{frame.shape[0]} but the "
                f"sequence started at {self.image[1]}x{self.image[0]}"
            )
        plan = self._plan
        if plan is not None and plan.number == frame.number and not fresh:
            return plan
        profile = self.profiles.get(frame)
        halo = self.forced_halo
        if halo is None:
            halo = halo_px(frame, profile)
        self.halos[frame.number] = halo
        windows = [window(c, halo, self.image) for c in self.cores]
        light = light_scale(frame, profile)
        crops = [crop_frame(frame, w, c, light) for w, c in zip(windows, self.cores)]
        st = self.stats
        st["frames"] += 1
        st["window_px"] += sum((w[1] - w[0]) * (w[3] - w[2]) for w in windows)
        st["image_px"] += self.image[0] * self.image[1]
        st["bytes_passes"] += sum(frame_nbytes(c) for c in crops)
        frames = [self.executor.scatter(c) for c in crops]
        self._plan = FramePlan(frame.number, halo, windows, frames)
        return self._plan


class TiledProcessor:
    """A method's processor whose frames are processed as tiles (module doc).

    Implements :class:`core.methods.Processor`; ``start(frame)`` submits the
    frame's tiles so that every method's work is queued before the first
    result is awaited (:meth:`core.run.SequenceRun.step` calls it).

    Parameters
    ----------
    name : method name
    params, options : as :func:`core.methods.make_processor`
    session : TileSession shared by the run's methods
    attempts : times a frame is submitted when its work is lost (``Executor.lost``)
    """

    def __init__(
        self,
        name: str,
        params: SSSParams,
        options: MethodOptions,
        session: TileSession,
        attempts: int = 3,
    ) -> None:
        self.method: Method = get_method(name)
        self.params = params
        self.options = options
        self.session = session
        self.attempts = attempts
        self._state: dict[str, np.ndarray] = {}
        self._last: list[Any] | None = None  # handles of the last frame's tile states
        self._pending: tuple[int, list[Any], list[Any]] | None = None
        self.resubmitted = 0

    # -- state -------------------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        """The whole image's state after the last processed frame."""
        return dict(self._state)

    def restore(self, state: Mapping[str, np.ndarray]) -> None:
        """Continue from a whole image's :meth:`state` (e.g. a checkpoint)."""
        self._state = {k: np.asarray(v) for k, v in state.items()}
        self._last = None
        self._pending = None

    def _history(self, image: tuple[int, int]) -> list[Any]:
        """Handles of the previous frame's pieces per tile core (seeded from the state)."""
        if self._last is not None:
            return self._last
        if not self._state:
            return []
        whole = split_state(self._state, (0, image[0], 0, image[1]))
        return [self.session.executor.scatter(crop_piece(whole, c)) for c in self.session.cores]

    # -- frames ------------------------------------------------------------------------------
    def start(self, frame: Frame, fresh: bool = False) -> None:
        """Submit the tiles of ``frame`` (the next frame of the sequence)."""
        if self._pending is not None and self._pending[0] == frame.number and not fresh:
            return
        ex = self.session.executor
        plan = self.session.plan(frame, fresh=fresh)
        previous = self._history(frame.shape)
        handles, states = [], []
        cores = self.session.cores
        for j, (box, crop) in enumerate(zip(plan.windows, plan.frames)):
            near = neighbours(cores, box) if previous else []
            # A neighbour's state is cut to the strip this window needs where it is held,
            # so a tile receives about its halo's pixels, not whole neighbouring tiles.
            history = [
                previous[i]
                if i == j
                else ex.submit(crop_piece, previous[i], _overlap(cores[i], box))
                for i in near
            ]
            out = ex.submit(
                _run_tile_job, self.method.name, self.params, self.options, crop, history
            )
            handles.append(out)
            # The next frame's neighbours need the state only: a job of its own runs where
            # the output is, so only the state travels between workers, not the images.
            states.append(ex.submit(_state_of, out))
        self._pending = (frame.number, handles, states)

    def process(self, frame: Frame) -> FrameResult:
        """The whole image's result of ``frame``, assembled from its tiles."""
        began = time.perf_counter()
        ex = self.session.executor
        waited = 0.0
        for attempt in range(self.attempts):
            self.start(frame, fresh=attempt > 0)
            try:
                t0 = time.perf_counter()
                outputs = ex.gather(self._pending[1])
                waited += time.perf_counter() - t0
                break
            except ex.lost as exc:
                # A worker died with part of this frame's work or of the history it
                # needed: tiles are pure, so submit the frame again from this
                # processor's own copy of the previous state.
                self.resubmitted += 1
                self._last = None
                if attempt + 1 == self.attempts:
                    raise
                if self.session.log:
                    self.session.log(
                        f"{self.method.name}: frame {frame.number}: work lost with a worker "
                        f"({type(exc).__name__}); submitting the frame again"
                    )
        image = frame.shape
        self._state = join_pieces([o.state for o in outputs], (0, image[0], 0, image[1]))
        # A stateless method's next frame needs nothing from this one.
        self._last = self._pending[2] if self._state else None
        self._pending = None
        result = assemble_result(
            [(o.core, o.result) for o in outputs],
            image,
            repaired=frame.repaired,
            total_ms=(time.perf_counter() - began) * 1e3,
        )
        st = self.session.stats
        st["tiles"] += len(outputs)
        st["work_s"] += sum(o.work_s for o in outputs)
        st["cpu_s"] += sum(o.cpu_s for o in outputs)
        for o in outputs:
            self.session.worker_cpu[o.worker] = self.session.worker_cpu.get(o.worker, 0.0) + o.cpu_s
        st["bytes_out"] += sum(o.nbytes for o in outputs)
        st["client_s"] += time.perf_counter() - began - waited
        return result


def _run_tile_job(name, params, options, frame, history) -> TileOutput:
    """:func:`run_tile` (a job: ``history`` holds the neighbours' StatePieces)."""
    return run_tile(name, params, options, frame, history)


def _state_of(output: TileOutput) -> StatePiece:
    return output.state
