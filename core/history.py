"""Per-pixel history buffers, their storage precision and reprojection.

Two histories per pixel, as in the paper (P Alg. 3):

- ``H = (μ, σ², m̄)``, three floats (SPVG);
- ``J = (Σ_xx, Σ_xy, Σ_yy, ζ_f, ζ_g)`` for the online control variate (the
  paper drops Σ_xx; we keep it for the α/variance maps, it costs one float).

Buffers are full-image (H, W) arrays stored in float32 or, to mimic GPU
RGBA16F render targets, float16. Arithmetic always happens in float64; only
storage rounds. In float16 the covariance entries are stored divided by η_cv:
with the paper's η_cv = 1e-6, Σ ≈ η_cv·(ΔZ)² would sit below float16's
smallest subnormal (6e-8) and flush to zero, whereas Σ/η_cv ≈ (ΔZ)² is well
inside the float16 range. Stored values are clipped to the finite range of
the storage type so HDR input never turns into inf.
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, field

import numpy as np

H_FIELDS = ("mu", "var", "mbar")
J_FIELDS = ("sxx", "sxy", "syy", "zf", "zg")
COV_FIELDS = ("sxx", "sxy", "syy")

#: Relative depth change beyond which a reprojected history is rejected.
REPROJECT_DEPTH_TOLERANCE = 0.1


def _storage(dtype: str) -> np.dtype:
    return np.dtype(np.float16 if dtype == "float16" else np.float32)


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

    @classmethod
    def empty(cls, shape: tuple[int, int], precision: str = "float32", eta_cv: float = 1.0) -> History:
        dt = _storage(precision)
        cov_scale = 1.0 / eta_cv if precision == "float16" else 1.0
        buffers = {name: np.zeros(shape, dtype=dt) for name in (*H_FIELDS, *J_FIELDS)}
        return cls(
            shape=tuple(shape),
            precision=precision,
            cov_scale=cov_scale,
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
    def read(self, name: str, index: np.ndarray) -> np.ndarray:
        """Values of a buffer at flat pixel ``index`` as float64, true units."""
        v = self.buffers[name].reshape(-1)[index].astype(np.float64)
        if name in COV_FIELDS:
            v /= self.cov_scale
        return v

    def write(self, name: str, index: np.ndarray, values: np.ndarray) -> None:
        """Store float64 ``values`` (true units) at flat ``index``, rounding to storage."""
        v = np.asarray(values, dtype=np.float64)
        if name in COV_FIELDS:
            v = v * self.cov_scale
        big = float(np.finfo(self.dtype).max)
        v = np.clip(np.nan_to_num(v, nan=0.0, posinf=big, neginf=-big), -big, big)
        self.buffers[name].reshape(-1)[index] = v.astype(self.dtype)

    def nbytes(self) -> int:
        """Bytes held by the per-pixel buffers (history storage cost)."""
        return sum(b.nbytes for b in self.buffers.values())

    # -- reprojection -------------------------------------------------------
    def reproject(
        self, motion: np.ndarray | None, depth: np.ndarray, material: np.ndarray
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

        Returns
        -------
        History (a new object; ``self`` is unchanged).
        """
        if depth.shape != self.shape:
            raise ValueError(
                f"history is {self.shape[1]}x{self.shape[0]} but the frame is "
                f"{depth.shape[1]}x{depth.shape[0]}"
            )
        h, w = self.shape
        if motion is None:
            src = np.arange(h * w)
            inside = np.ones(h * w, dtype=bool)
        else:
            yy, xx = np.mgrid[0:h, 0:w]
            px = np.rint(xx + motion[..., 0]).astype(np.int64).reshape(-1)
            py = np.rint(yy + motion[..., 1]).astype(np.int64).reshape(-1)
            inside = (px >= 0) & (px < w) & (py >= 0) & (py < h)
            src = np.where(inside, py * w + px, 0)
        prev_depth = self.depth.reshape(-1)[src].astype(np.float64)
        cur_depth = depth.reshape(-1).astype(np.float64)
        with np.errstate(invalid="ignore"):
            close = np.abs(prev_depth - cur_depth) <= REPROJECT_DEPTH_TOLERANCE * cur_depth
        same = inside & (self.material.reshape(-1)[src] == material.reshape(-1)) & close
        out = History(
            shape=self.shape,
            precision=self.precision,
            cov_scale=self.cov_scale,
            frame=self.frame,
            buffers={k: v.reshape(-1)[src].reshape(self.shape) for k, v in self.buffers.items()},
            valid=(self.valid.reshape(-1)[src] & same).reshape(self.shape),
            cv_valid=(self.cv_valid.reshape(-1)[src] & same).reshape(self.shape),
            material=np.asarray(material, dtype=np.int32).copy(),
            depth=np.asarray(depth, dtype=np.float32).copy(),
        )
        return out

    # -- checkpoints --------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Write the history atomically as a compressed ``.npz`` checkpoint."""
        path = os.fspath(path)
        arrays = {f"buf_{k}": v for k, v in self.buffers.items()}
        meta = np.array([self.shape[0], self.shape[1], -1 if self.frame is None else self.frame])
        buf = io.BytesIO()
        np.savez_compressed(
            buf,
            meta=meta,
            precision=np.array(self.precision),
            cov_scale=np.array(self.cov_scale),
            valid=self.valid,
            cv_valid=self.cv_valid,
            material=self.material,
            depth=self.depth,
            **arrays,
        )
        tmp = f"{path}.tmp-{os.getpid()}"
        with open(tmp, "wb") as fh:
            fh.write(buf.getvalue())
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> History:
        """Read a checkpoint written by :meth:`save`."""
        with np.load(os.fspath(path), allow_pickle=False) as data:
            h, w, frame = (int(v) for v in data["meta"])
            buffers = {k[4:]: data[k].copy() for k in data.files if k.startswith("buf_")}
            return cls(
                shape=(h, w),
                precision=str(data["precision"]),
                cov_scale=float(data["cov_scale"]),
                frame=None if frame < 0 else frame,
                buffers=buffers,
                valid=data["valid"].copy(),
                cv_valid=data["cv_valid"].copy(),
                material=data["material"].copy(),
                depth=data["depth"].copy(),
            )
