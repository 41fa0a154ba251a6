"""Low-discrepancy sequences and hashes for per-pixel sampling."""

from .qmc import pcg3d, pixel_hashes, pixel_offsets, r2_points, r2_points_fixed

__all__ = ["pcg3d", "pixel_hashes", "pixel_offsets", "r2_points", "r2_points_fixed"]
