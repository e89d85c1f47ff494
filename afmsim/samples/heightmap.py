"""The height-map data carrier: a topography that knows its own physical grid."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HeightMap"]


@dataclass(frozen=True, eq=False)
class HeightMap:
    """Heights on a regular grid, in metres.

    Conventions (pinned by tests): rows are scan lines along +y, columns are pixels along +x
    (left → right, the trace direction); ``z[k, l]`` is the height at
    ``x = origin[0] + l·pixel_size[0]``, ``y = origin[1] + k·pixel_size[1]`` (pixel centres).

    Attributes
    ----------
    z : ndarray, shape (ny, nx)
        Heights in metres.
    pixel_size : (float, float)
        Pixel pitch (dx, dy) in metres, both > 0.
    origin : (float, float)
        Position (x, y) of the centre of pixel ``z[0, 0]`` in metres.
    """

    z: np.ndarray
    pixel_size: tuple[float, float]
    origin: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        z = np.asarray(self.z, dtype=np.float64)
        if z.ndim != 2 or min(z.shape) < 2:
            raise ValueError(f"height map must be 2-D with at least 2×2 pixels, got shape {z.shape}")
        if not np.all(np.isfinite(z)):
            raise ValueError("height map contains NaN or inf")
        dx, dy = (float(v) for v in self.pixel_size)
        if not (dx > 0 and dy > 0):
            raise ValueError(f"pixel_size must be > 0 in both axes, got {self.pixel_size}")
        object.__setattr__(self, "z", z)
        object.__setattr__(self, "pixel_size", (dx, dy))
        object.__setattr__(self, "origin", tuple(float(v) for v in self.origin))

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx)."""
        return self.z.shape

    @property
    def x(self) -> np.ndarray:
        """Pixel-centre x coordinates, metres, shape (nx,)."""
        return self.origin[0] + self.pixel_size[0] * np.arange(self.z.shape[1])

    @property
    def y(self) -> np.ndarray:
        """Pixel-centre y coordinates, metres, shape (ny,)."""
        return self.origin[1] + self.pixel_size[1] * np.arange(self.z.shape[0])

    @property
    def size(self) -> tuple[float, float]:
        """Physical size (width, height) = (nx·dx, ny·dy) in metres."""
        return (self.z.shape[1] * self.pixel_size[0], self.z.shape[0] * self.pixel_size[1])

    def with_z(self, z: np.ndarray) -> "HeightMap":
        """A new map on the same grid with other heights."""
        return HeightMap(z, self.pixel_size, self.origin)
