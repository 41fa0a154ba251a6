"""Per-pixel history buffers, their storage precision and reprojection.

Two histories per pixel, as in the paper (P Alg. 3):

- ``H = (μ, σ², m̄)``, three floats (SPVG);
- ``J = (Σ_xx, Σ_xy, Σ_yy, ζ_f, ζ_g)`` for the online control variate (the
  paper drops Σ_xx; we keep it for the α/variance maps, it costs one float);
  the methods without one hold no J;
- with temporal reuse, the accumulated value and its frame count, and last
  frame's proxy and control (:data:`T_FIELDS`, 10 floats; core.mc.temporal).

Buffers are full-image (H, W) arrays stored in float32 or, to mimic GPU
RGBA16F render targets, float16. Arithmetic always happens in float64; only
storage rounds. Stored values are clipped to the finite range of the storage
type so HDR input never turns into inf.

float16 storage is scaled so that what the algorithm compares lands in the
half-precision range (measured by ``cvsss fp16``):

- the covariance entries are stored divided by η_cv. With the paper's
  η_cv = 1e-6, Σ ≈ η_cv·(ΔZ)² sits below float16's smallest subnormal
  (6e-8) and flushes to zero, which silently turns the online control
  variate into α = 1; Σ/η_cv ≈ n·(ΔZ)² after n frames is well inside the
  range (it saturates at 65504 only once n·Var(Z) exceeds it);
- the tracked variance is stored divided by σ0²: the counts depend on
  σ²/σ0² only, the no-history value is exactly 1, and σ0² = 1e-12 (which
  would flush to 0 and drive counts to β_min) or σ0² = 1e6 (which would
  overflow 65504 and drive counts to β_min) stay representable. A stored
  ratio that saturates at 65504 already asks for more than β_max ≤ 4096.

μ, m̄ and ζ are stored unscaled: a tracked (exposure-scaled) luminance above
65504 saturates in float16, so HDR sequences need ``exposure`` or float32.
float32 storage is never scaled.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..backends.twins import compiled_module, compiled_side, numpy_side

H_FIELDS = ("mu", "var", "mbar")
J_FIELDS = ("sxx", "sxy", "syy", "zf", "zg")
COV_FIELDS = ("sxx", "sxy", "syy")
#: Temporal reuse (core.mc.temporal): accumulated value per channel, frames
#: accumulated, and last frame's proxy and control per channel.
T_FIELDS = (
    "acc_r",
    "acc_g",
    "acc_b",
    "acc_n",
    "prox_r",
    "prox_g",
    "prox_b",
    "ctl_r",
    "ctl_g",
    "ctl_b",
)
#: Buffers that are zeroed where the reprojection finds no matching surface.
RESET_FIELDS = ("acc_n",)

#: Relative depth change beyond which a reprojected history is rejected.
REPROJECT_DEPTH_TOLERANCE = 0.1


_FINITE_MAX = {
    "float32": float(np.finfo(np.float32).max),
    "float16": float(np.finfo(np.float16).max),
}


def _storage(dtype: str) -> np.dtype:
    return np.dtype(np.float16 if dtype == "float16" else np.float32)


def _still(motion: np.ndarray | None) -> bool:
    """Every pixel is its own source: no motion, or less than half a pixel everywhere
    (the rounded source is then the pixel itself; a still camera's motion pass holds
    such tiny values; NaN is not still)."""
    return motion is None or bool(motion.max() < 0.5 and motion.min() > -0.5)


def _same_surface(prev_depth, prev_material, depth, material) -> np.ndarray:
    """(H·W,) bool: each pixel's surface is the one its source held: the same slot, and
    the depth changed by at most :data:`REPROJECT_DEPTH_TOLERANCE` (relative, in
    float64; NaN or infinite depth never matches). ``prev_depth``, ``prev_material``:
    the source's, read at each pixel (the history's own arrays where each pixel is its
    own source)."""
    prev = np.asarray(prev_depth).reshape(-1).astype(np.float64)
    cur = np.asarray(depth).reshape(-1).astype(np.float64)
    with np.errstate(invalid="ignore"):
        close = np.abs(prev - cur) <= REPROJECT_DEPTH_TOLERANCE * cur
    return (np.asarray(prev_material).reshape(-1) == np.asarray(material).reshape(-1)) & close


def _block(buffers: list[np.ndarray], shape: tuple[int, int], dtype: np.dtype) -> np.ndarray:
    """(F, H, W): the F buffers as the rows of one C-contiguous array: the array they
    are the rows of, in order (as :meth:`History.empty` and the compiled reprojection
    make them), else a stacked copy."""
    if not buffers:
        return np.zeros((0, *shape), dtype)
    base = buffers[0].base
    if (
        isinstance(base, np.ndarray)
        and base.shape == (len(buffers), *shape)
        and base.dtype == dtype
        and base.flags.c_contiguous
    ):
        start = base.__array_interface__["data"][0]
        if all(
            b.base is base
            and b.shape == shape
            and b.dtype == dtype
            and b.__array_interface__["data"][0] == start + i * base.strides[0]
            and b.flags.c_contiguous
            for i, b in enumerate(buffers)
        ):
            return base
    return np.stack(buffers)


@dataclass
class History:
    """History of one image, aligned with the frame it was last updated on.

    Attributes
    ----------
    shape : (H, W)
    precision : {"float32", "float16"}
    cov_scale : float
        Stored covariance = true covariance × ``cov_scale`` (1/η_cv in
        float16, 1 in float32).
    var_scale : float
        Stored σ² = true σ² × ``var_scale`` (1/σ0² in float16, 1 in float32).
    frame : int or None
        Frame number of the last update (None = empty).
    buffers : dict of (H, W) arrays in the storage dtype (μ, σ², m̄, Σ, ζ)
    valid : (H, W) bool, H is valid (the pixel took samples)
    cv_valid : (H, W) bool, J is valid
    material : (H, W) int32, slot of the pixel at the last update
    depth : (H, W) float32, depth at the last update (scene units)
    """

    shape: tuple[int, int]
    precision: str = "float32"
    cov_scale: float = 1.0
    frame: int | None = None
    buffers: dict[str, np.ndarray] = field(default_factory=dict)
    valid: np.ndarray | None = None
    cv_valid: np.ndarray | None = None
    material: np.ndarray | None = None
    depth: np.ndarray | None = None
    var_scale: float = 1.0

    @staticmethod
    def fields(temporal: bool, cv: bool) -> tuple[str, ...]:
        """The buffers a history holds: :data:`H_FIELDS`, with ``cv`` the online control
        variate's :data:`J_FIELDS`, with ``temporal`` :data:`T_FIELDS`."""
        return (*H_FIELDS, *(J_FIELDS if cv else ()), *(T_FIELDS if temporal else ()))

    @classmethod
    def empty(
        cls,
        shape: tuple[int, int],
        precision: str = "float32",
        eta_cv: float = 1.0,
        target_variance: float = 1.0,
        *,
        scaled: bool = True,
        temporal: bool = False,
        cv: bool = True,
    ) -> History:
        """An all-invalid history.

        Parameters
        ----------
        shape : (H, W)
        precision : {"float32", "float16"}
        eta_cv : float in (0, 1], η_cv (float16 covariance scale 1/η_cv)
        target_variance : float > 0, σ0² (float16 variance scale 1/σ0²)
        scaled : bool
            False stores float16 values unscaled, which underflows at the
            paper's η_cv (kept only to measure that; see module doc).
        temporal : bool
            Also hold the temporal-reuse buffers (:data:`T_FIELDS`).
        cv : bool
            Hold the online control variate's J (:data:`J_FIELDS`). A method
            without one leaves them out: five buffers fewer to reproject and
            store each frame.
        """
        dt = _storage(precision)
        half = precision == "float16" and scaled
        names = cls.fields(temporal, cv)
        # The buffers are the rows of one array (see _block): the compiled reprojection
        # fetches them all in one pass.
        buffers = dict(zip(names, np.zeros((len(names), *shape), dtype=dt)))
        return cls(
            shape=tuple(shape),
            precision=precision,
            cov_scale=1.0 / eta_cv if half else 1.0,
            var_scale=1.0 / target_variance if half else 1.0,
            buffers=buffers,
            valid=np.zeros(shape, dtype=bool),
            cv_valid=np.zeros(shape, dtype=bool),
            material=np.zeros(shape, dtype=np.int32),
            depth=np.full(shape, np.inf, dtype=np.float32),
        )

    @property
    def dtype(self) -> np.dtype:
        return _storage(self.precision)

    # -- access -------------------------------------------------------------
    def scale(self, name: str) -> float:
        """Stored value of buffer ``name`` = true value × this factor."""
        if name in COV_FIELDS:
            return self.cov_scale
        if name == "var":
            return self.var_scale
        return 1.0

    def read(self, name: str, index: np.ndarray, backend: str = "numpy") -> np.ndarray:
        """(P,) float64 values of buffer ``name`` at flat pixel ``index``, true units
        (:meth:`read_columns` of one buffer)."""
        return self.read_columns((name,), index, backend)[:, 0]

    def write(
        self, name: str, index: np.ndarray, values: np.ndarray, backend: str = "numpy"
    ) -> None:
        """Store float64 ``values`` (true units) at flat ``index``, rounding to storage
        (:meth:`write_columns` of one buffer)."""
        v = np.asarray(values, dtype=np.float64)
        self.write_columns((name,), index, v.reshape(-1, 1), backend)

    @numpy_side("history_read")
    def read_columns(self, names, index: np.ndarray, backend: str = "numpy") -> np.ndarray:
        """(P, k) float64: the k buffers ``names`` at flat pixel ``index``, one column
        each, in true units (stored values divided by :meth:`scale`).

        Where ``backend`` resolves to numba and the buffers are float32, one compiled
        pass per buffer (:meth:`_read_compiled`), the same values.
        """
        columns = []
        for name in names:
            v = self.buffers[name].reshape(-1)[index].astype(np.float64)
            scale = self.scale(name)
            if scale != 1.0:
                v /= scale
            columns.append(v)
        return np.stack(columns, axis=-1)

    @numpy_side("history_write")
    def write_columns(
        self, names, index: np.ndarray, values: np.ndarray, backend: str = "numpy"
    ) -> None:
        """Store each column of ``values`` ((P, k) float, true units) into the buffer of
        the same position in ``names`` at flat ``index``: times :meth:`scale`, clipped
        to the storage type's finite range (±inf too), NaN stored as 0, rounded.

        Where ``backend`` resolves to numba and the buffers are float32, one compiled
        pass per buffer (:meth:`_write_compiled`), the same stores.
        """
        values = np.asarray(values, dtype=np.float64)
        big = _FINITE_MAX["float16" if self.precision == "float16" else "float32"]
        for c, name in enumerate(names):
            v = values[:, c]
            scale = self.scale(name)
            if scale != 1.0:
                with np.errstate(over="ignore"):
                    v = v * scale
            v = np.clip(v, -big, big)  # ±inf -> ±big; NaN stays NaN ...
            nan = np.isnan(v)
            if nan.any():
                v[nan] = 0.0  # ... and is stored as 0
            self.buffers[name].reshape(-1)[index] = v.astype(self.dtype)

    def compiled_io(self, index: np.ndarray, names) -> bool:
        """Compiled passes can read and write the buffers ``names`` at ``index`` in
        place: int64 indices and contiguous float32 buffers (numba stores no float16; a
        flat view of a contiguous buffer is the buffer itself, so a write lands in it).
        The compiled history step asks the same (:mod:`core.mc.update`)."""
        if getattr(index, "dtype", None) != np.int64:
            return False
        return all(
            self.buffers[n].dtype == np.float32 and self.buffers[n].flags.c_contiguous
            for n in names
        )

    def _io_compiled(self, names, index, *_args, **_kwargs) -> bool:
        """``supports`` of the compiled reads and writes: :meth:`compiled_io`."""
        return self.compiled_io(index, names)

    @compiled_side("history_read", supports=_io_compiled)
    def _read_compiled(self, names, index: np.ndarray, backend: str = "numpy") -> np.ndarray:
        """:meth:`read_columns` where :meth:`compiled_io` holds: one pass per buffer."""
        read_column = compiled_module("history").read_column
        # Contiguous (no copy where already so): the passes' compiled layout.
        index = np.ascontiguousarray(index)
        out = np.empty((index.shape[0], len(names)))
        for c, name in enumerate(names):
            read_column(self.buffers[name].reshape(-1), index, self.scale(name), out, c)
        return out

    @compiled_side("history_write", supports=_io_compiled)
    def _write_compiled(
        self, names, index: np.ndarray, values: np.ndarray, backend: str = "numpy"
    ) -> None:
        """:meth:`write_columns` where :meth:`compiled_io` holds: one pass per buffer."""
        write_column = compiled_module("history").write_column
        values = np.asarray(values, dtype=np.float64)
        # One row per pixel, as NumPy's assignment broadcasts a scalar or a row, in
        # the passes' compiled type: contiguous and writable (numba types a read-only
        # array apart, and would compile again); no copy where it is.
        index = np.ascontiguousarray(index)
        shape = (index.shape[0], len(names))
        if values.shape != shape:
            values = np.broadcast_to(values, shape)
        if not (values.flags.c_contiguous and values.flags.writeable):
            values = np.array(values, order="C")
        for c, name in enumerate(names):
            write_column(values, c, index, self.scale(name), self.buffers[name].reshape(-1))

    def mask_of(self, index: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(H, W) bool image: ``values`` at flat ``index``, False elsewhere."""
        out = np.zeros(self.shape[0] * self.shape[1], dtype=bool)
        out[index] = values
        return out.reshape(self.shape)

    def nbytes(self) -> int:
        """Bytes held by the per-pixel buffers (history storage cost)."""
        return sum(b.nbytes for b in self.buffers.values())

    # -- reprojection -------------------------------------------------------
    @numpy_side("reproject")
    def reproject(
        self,
        motion: np.ndarray | None,
        depth: np.ndarray,
        material: np.ndarray,
        backend: str = "numpy",
        in_place: bool = False,
    ) -> History:
        """History aligned with the current frame.

        Each current pixel fetches the history of the pixel its surface came
        from (``motion`` points to the previous position, pixels, x right and
        y down). The fetched history is valid only if it was valid, the
        material slot matches and the depth changed by at most 10 %
        (disocclusion otherwise).

        Parameters
        ----------
        motion : (H, W, 2) float or None (static)
        depth : (H, W) float, current depth (inf = background)
        material : (H, W) int, current slot
        backend : one of core.params.BACKENDS; where it resolves to numba (and the
            passes are float32 and integer, as a Frame holds them) the mapping and
            the fetches are compiled passes with the same arithmetic
            (:meth:`_reproject_compiled`): the same history
        in_place : bool
            Where every pixel is its own source (``motion`` None or below half a
            pixel everywhere: a still camera), align ``self`` and return it, its
            buffers not copied: only the pixels whose surface changed are reset.
            For a caller that owns the history: nothing else may hold its arrays
            (a state from :meth:`to_arrays`, say).

        Returns
        -------
        History (a new object, ``self`` unchanged; or ``self``, see ``in_place``).
        """
        self._check_shape(depth)
        if in_place and _still(motion):
            same = _same_surface(self.depth, self.material, depth, material)
            return self._align_in_place(same.reshape(self.shape), depth, material)
        h, w = self.shape
        if motion is None:
            src = np.arange(h * w)
            inside = np.ones(h * w, dtype=bool)
        else:
            yy, xx = np.mgrid[0:h, 0:w]
            fx = (xx + np.asarray(motion[..., 0], dtype=np.float64)).reshape(-1)
            fy = (yy + np.asarray(motion[..., 1], dtype=np.float64)).reshape(-1)
            # Huge or non-finite motion points off screen; clip before the
            # integer cast so it cannot overflow.
            finite = np.isfinite(fx) & np.isfinite(fy)
            px = np.rint(np.clip(np.where(finite, fx, -1.0), -1.0, w)).astype(np.int64)
            py = np.rint(np.clip(np.where(finite, fy, -1.0), -1.0, h)).astype(np.int64)
            inside = finite & (px >= 0) & (px < w) & (py >= 0) & (py < h)
            src = np.where(inside, py * w + px, 0)
        prev_depth = self.depth.reshape(-1)[src]
        prev_material = self.material.reshape(-1)[src]
        same = inside & _same_surface(prev_depth, prev_material, depth, material)
        outside = ~inside

        def fetch(buffer: np.ndarray) -> np.ndarray:
            # A pixel with no source gets zeros, not its neighbour's leftovers: the
            # history is then a function of the image alone, which a tiled run
            # (core.tiling) reproduces bit for bit.
            out = buffer.reshape(-1)[src]
            out[outside] = 0
            return out.reshape(self.shape)

        buffers = {k: fetch(v) for k, v in self.buffers.items()}
        for name in RESET_FIELDS:
            if name in buffers:
                buffers[name] = np.where(same.reshape(self.shape), buffers[name], 0).astype(
                    self.dtype
                )
        return self._aligned(
            buffers,
            (self.valid.reshape(-1)[src] & same).reshape(self.shape),
            (self.cv_valid.reshape(-1)[src] & same).reshape(self.shape),
            depth,
            material,
        )

    def _align_in_place(self, same: np.ndarray, depth, material) -> History:
        """``self`` aligned where each pixel is its own source (:meth:`reproject` with
        ``in_place``): the reset buffers and the masks cleared where ``same`` is False,
        the current depth and slots kept."""
        for name in RESET_FIELDS:
            if name in self.buffers:
                np.putmask(self.buffers[name], ~same, 0)
        self.valid &= same
        self.cv_valid &= same
        self.material[...] = material
        self.depth[...] = depth
        return self

    def _aligned(self, buffers, valid, cv_valid, depth, material) -> History:
        """The reprojected history: these buffers and masks, the current depth and slots."""
        return History(
            shape=self.shape,
            precision=self.precision,
            cov_scale=self.cov_scale,
            var_scale=self.var_scale,
            frame=self.frame,
            buffers=buffers,
            valid=valid,
            cv_valid=cv_valid,
            material=np.asarray(material, dtype=np.int32).copy(),
            depth=np.asarray(depth, dtype=np.float32).copy(),
        )

    def _check_shape(self, depth: np.ndarray) -> None:
        if depth.shape != self.shape:
            raise ValueError(
                f"history is {self.shape[1]}x{self.shape[0]} but the frame is "
                f"{depth.shape[1]}x{depth.shape[0]}"
            )

    def _frame_dtypes(self, motion, depth, material, backend="numpy", in_place=False) -> bool:
        """``supports`` of the compiled reprojection: the passes' Frame dtypes, and
        buffers of the storage dtype and the image's shape."""
        return (
            depth.dtype == np.float32
            and np.asarray(material).dtype.kind in "iu"
            and (motion is None or motion.dtype == np.float32)
            and self.depth.dtype == np.float32
            and all(b.dtype == self.dtype and b.shape == self.shape for b in self.buffers.values())
        )

    @compiled_side("reproject", supports=_frame_dtypes)
    def _reproject_compiled(
        self, motion, depth, material, backend="numpy", in_place=False
    ) -> History:
        """:meth:`reproject` as one compiled pass over the pixels: the source pixels, and
        every buffer and mask fetched (the same history). The new buffers are the rows
        of one array, as :meth:`empty` makes them. In place, the surface test is one
        compiled pass (:func:`_same_surface`'s arithmetic), then
        :meth:`_align_in_place`."""
        self._check_shape(depth)
        if in_place and _still(motion):
            same = compiled_module("history").surface_kept(
                depth, material, self.depth, self.material, REPROJECT_DEPTH_TOLERANCE
            )
            return self._align_in_place(same, depth, material)
        names = list(self.buffers)
        block = _block(list(self.buffers.values()), self.shape, self.dtype)
        reset = np.array([name in RESET_FIELDS for name in names], dtype=bool)
        out, valid, cv_valid = compiled_module("history").reproject(
            motion, depth, material, self.depth, self.material, REPROJECT_DEPTH_TOLERANCE,
            block, reset, self.valid, self.cv_valid,
        )  # fmt: skip
        return self._aligned(dict(zip(names, out)), valid, cv_valid, depth, material)

    # -- checkpoints --------------------------------------------------------
    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        """Every field as named arrays (exact: storage dtypes are kept).

        :meth:`from_arrays` inverts it bit for bit, so a sequence resumed
        from a checkpoint continues exactly as an uninterrupted run.
        """
        # The shape is the pixel arrays' own: the state of a crop is then the crop of
        # the state (core.tiling crops and assembles states without knowing them).
        meta = np.array([-1 if self.frame is None else self.frame])
        arrays = {
            "meta": meta,
            "precision": np.array(self.precision),
            "cov_scale": np.array(self.cov_scale, dtype=np.float64),
            "var_scale": np.array(self.var_scale, dtype=np.float64),
            "valid": self.valid,
            "cv_valid": self.cv_valid,
            "material": self.material,
            "depth": self.depth,
            **{f"buf_{k}": v for k, v in self.buffers.items()},
        }
        return {prefix + k: v for k, v in arrays.items()}

    @staticmethod
    def check_arrays(arrays, prefix: str = "", fields: tuple[str, ...] = ()) -> tuple[int, int]:
        """Check that ``arrays`` hold a history as :meth:`to_arrays` writes it.

        :meth:`from_arrays` and the compiled kernels index the buffers with the
        frame's pixel indices unchecked: a buffer of another shape would read and
        write out of bounds. A checkpoint is therefore checked with this before it
        is restored.

        Parameters
        ----------
        arrays : mapping name -> array (or an open ``.npz``)
        prefix : str, prefix of the history's names (``"h_"`` in a processor state)
        fields : buffer names that must be present (``buf_<name>``), e.g.
            :data:`H_FIELDS` and :data:`J_FIELDS`; other buffers are allowed

        Returns
        -------
        (H, W), the image shape every pixel array shares.

        Raises
        ------
        ValueError
            An array is missing or has the wrong shape, dtype or value; the
            message names it.
        """
        keys = set(arrays.keys()) if hasattr(arrays, "keys") else set(arrays.files)

        def get(key: str) -> np.ndarray:
            if prefix + key not in keys:
                raise ValueError(f"no array {prefix + key}")
            return np.asarray(arrays[prefix + key])

        def scalar(key: str, kinds: str) -> np.ndarray:
            value = get(key)
            if value.shape != () or value.dtype.kind not in kinds:
                raise ValueError(
                    f"{prefix + key} must be a scalar of kind {kinds!r}, "
                    f"got shape {value.shape} dtype {value.dtype}"
                )
            return value

        meta = get("meta")
        if meta.ndim != 1 or meta.shape[0] not in (1, 3) or meta.dtype.kind not in "iu":
            raise ValueError(
                f"{prefix}meta must be 1 or 3 integers, got shape {meta.shape} dtype {meta.dtype}"
            )
        precision = str(scalar("precision", "U"))
        if precision not in _FINITE_MAX:
            raise ValueError(f"{prefix}precision must be float32 or float16, got {precision!r}")
        for key in ("cov_scale", "var_scale"):
            if key == "var_scale" and prefix + key not in keys:
                continue  # checkpoints written before var_scale existed
            value = float(scalar(key, "f"))
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{prefix + key} must be finite and > 0, got {value!r}")
        valid = get("valid")
        if valid.ndim != 2 or 0 in valid.shape:
            raise ValueError(f"{prefix}valid must be an (H, W) image, got shape {valid.shape}")
        shape = (int(valid.shape[0]), int(valid.shape[1]))
        want = {
            "valid": np.dtype(bool),
            "cv_valid": np.dtype(bool),
            "material": np.dtype(np.int32),
            "depth": np.dtype(np.float32),
        }
        want.update(dict.fromkeys((f"buf_{name}" for name in fields), _storage(precision)))
        start = prefix + "buf_"
        for key in sorted(keys):
            if key.startswith(start):
                want.setdefault(key[len(prefix) :], _storage(precision))
        for key, dtype in want.items():
            value = get(key)
            if value.shape != shape or value.dtype != dtype:
                raise ValueError(
                    f"{prefix + key} must be {shape[0]}x{shape[1]} {dtype}, got shape "
                    f"{value.shape} dtype {value.dtype}"
                )
        return shape

    @classmethod
    def from_arrays(cls, arrays, prefix: str = "") -> History:
        """Inverse of :meth:`to_arrays` (``arrays``: a mapping or an open ``.npz``,
        checked with :meth:`check_arrays` where it comes from a file)."""

        def get(key: str) -> np.ndarray:
            return np.asarray(arrays[prefix + key]).copy()

        keys = list(arrays.keys()) if hasattr(arrays, "keys") else list(arrays.files)
        # meta is [frame] ([h, w, frame] in checkpoints before tiling): the shape is the
        # pixel arrays'.
        frame = int(get("meta")[-1])
        h, w = np.shape(arrays[prefix + "valid"])
        start = prefix + "buf_"
        names = [k for k in keys if k.startswith(start)]
        loaded = [np.asarray(arrays[k]) for k in names]
        if loaded and all(
            a.dtype == loaded[0].dtype and a.shape == loaded[0].shape for a in loaded
        ):
            copies = list(np.stack(loaded))  # the rows of one array, as empty() makes them
        else:
            copies = [a.copy() for a in loaded]
        buffers = {k[len(start) :]: v for k, v in zip(names, copies)}
        # Checkpoints written before var_scale existed stored σ² unscaled.
        var_scale = float(get("var_scale")) if prefix + "var_scale" in keys else 1.0
        return cls(
            shape=(h, w),
            precision=str(get("precision")),
            cov_scale=float(get("cov_scale")),
            var_scale=var_scale,
            frame=None if frame < 0 else frame,
            buffers=buffers,
            valid=get("valid"),
            cv_valid=get("cv_valid"),
            material=get("material"),
            depth=get("depth"),
        )
