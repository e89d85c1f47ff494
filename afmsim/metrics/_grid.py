"""Pixel-grid helpers shared by the metrics modules (internal)."""

from __future__ import annotations

import numpy as np

__all__ = ["as_image", "as_pixel_size"]


def as_pixel_size(pixel_size) -> tuple[float, float]:
    """Normalise ``pixel_size`` to ``(dx, dy)`` in metres.

    Accepts a scalar (square pixels) or a pair ``(dx, dy)``; both must be finite and > 0.
    """
    arr = np.atleast_1d(np.asarray(pixel_size, dtype=np.float64))
    if arr.size == 1:
        dx = dy = float(arr[0])
    elif arr.size == 2:
        dx, dy = float(arr[0]), float(arr[1])
    else:
        raise ValueError(f"pixel_size must be a scalar or a pair (dx, dy), got {pixel_size!r}")
    if not (np.isfinite(dx) and np.isfinite(dy) and dx > 0 and dy > 0):
        raise ValueError(f"pixel_size must be finite and > 0, got {pixel_size!r}")
    return dx, dy


def as_image(image, name: str = "image", min_size: int = 2) -> np.ndarray:
    """Return ``image`` as a finite 2-D float64 array (rows = y scan lines, columns = x)."""
    z = np.asarray(image, dtype=np.float64)
    if z.ndim != 2 or min(z.shape) < min_size:
        raise ValueError(f"{name} must be a 2-D array with at least {min_size}×{min_size} pixels, "
                         f"got shape {z.shape}")
    if not np.all(np.isfinite(z)):
        raise ValueError(f"{name} contains NaN or inf")
    return z
