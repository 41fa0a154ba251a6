"""Low-discrepancy sequences and hashes for per-pixel sampling."""

from .sequence import pcg3d, pixel_offsets, r2_points

__all__ = ["pcg3d", "pixel_offsets", "r2_points"]
