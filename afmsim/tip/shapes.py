"""AFM tip shapes as height functions, and their sampling on a sample's pixel grid.

Convention: a tip is described by its **surface height above the apex**, ``t(x, y) ≥ 0`` [m], with
``t(0, 0) = 0`` at the apex and growing away from it (the tip body lies above ``t``). ``(x, y)``
is the lateral offset from the apex, same axes as :class:`~afmsim.samples.heightmap.HeightMap`.

Defaults: Bruker MLCT (silicon nitride) — datasheet row "MLCT tip" (M confidence): apex radius
20 nm nominal (60 nm max); angles front 15°, back 25°, side 17.5° (± 2.5°); tip height 2.5–8 µm.
The symmetric cone here uses one half-angle, default 20° (between the side and back angles); an
asymmetric MLCT can be passed as an :class:`ArrayTip`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ParabolicTip", "ConeTip", "ArrayTip", "mlct_tip", "tip_array", "MLCT_APEX_RADIUS",
           "MLCT_HALF_ANGLE_DEG"]

MLCT_APEX_RADIUS = 20e-9  # m, nominal (datasheet, M)
MLCT_HALF_ANGLE_DEG = 20.0  # deg, between side 17.5° and back 25° (datasheet, M)


@dataclass(frozen=True)
class ParabolicTip:
    """Paraboloid of revolution ``t(r) = r² / (2R)``; R = apex radius of curvature [m]."""

    apex_radius: float = MLCT_APEX_RADIUS

    def __post_init__(self):
        if not self.apex_radius > 0:
            raise ValueError(f"apex_radius must be > 0, got {self.apex_radius}")

    def height(self, x, y) -> np.ndarray:
        """Tip surface height above the apex [m] at lateral offsets (x, y) [m]."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        return (x * x + y * y) / (2 * self.apex_radius)

    def radius_at_height(self, h: float) -> float:
        """Lateral radius [m] where the tip surface reaches height h [m]."""
        return float(np.sqrt(2 * self.apex_radius * max(h, 0.0)))


@dataclass(frozen=True)
class ConeTip:
    """Cone of half-angle α (from the axis) with a tangent spherical apex of radius R.

    ``t(r) = R − √(R² − r²)`` for ``r ≤ R cos α`` (sphere), else
    ``t(r) = R(1 − sin α) + (r − R cos α) / tan α`` (cone; C¹ at the junction).
    """

    apex_radius: float = MLCT_APEX_RADIUS
    half_angle_deg: float = MLCT_HALF_ANGLE_DEG

    def __post_init__(self):
        if not self.apex_radius > 0:
            raise ValueError(f"apex_radius must be > 0, got {self.apex_radius}")
        if not (0 < self.half_angle_deg < 90):
            raise ValueError(f"half_angle_deg must be in (0, 90), got {self.half_angle_deg}")

    def height(self, x, y) -> np.ndarray:
        """Tip surface height above the apex [m] at lateral offsets (x, y) [m]."""
        R, a = self.apex_radius, np.radians(self.half_angle_deg)
        r = np.hypot(np.asarray(x, float), np.asarray(y, float))
        rt = R * np.cos(a)
        sphere = R - np.sqrt(np.maximum(R * R - np.minimum(r, rt) ** 2, 0.0))
        cone = R * (1 - np.sin(a)) + (r - rt) / np.tan(a)
        return np.where(r <= rt, sphere, cone)

    def radius_at_height(self, h: float) -> float:
        """Lateral radius [m] where the tip surface reaches height h [m]."""
        R, a = self.apex_radius, np.radians(self.half_angle_deg)
        h = max(h, 0.0)
        if h <= R * (1 - np.sin(a)):
            return float(np.sqrt(max(R * R - (R - h) ** 2, 0.0)))
        return float(R * np.cos(a) + (h - R * (1 - np.sin(a))) * np.tan(a))


@dataclass(frozen=True, eq=False)
class ArrayTip:
    """A tip given as samples ``t[j, i]`` ≥ 0 [m] at offsets ``((i − ci)·dx, (j − cj)·dy)``.

    ``t`` must have odd shape with its apex (value 0, the minimum) at the centre; use it for
    measured/reconstructed or asymmetric tips. It is only valid on its own ``pixel_size``;
    beyond its footprint the tip is treated as infinitely high (never touches).
    """

    t: np.ndarray
    pixel_size: tuple[float, float]

    def __post_init__(self):
        t = np.asarray(self.t, float)
        if t.ndim != 2 or t.shape[0] % 2 == 0 or t.shape[1] % 2 == 0:
            raise ValueError(f"ArrayTip needs a 2-D array of odd shape, got {t.shape}")
        cj, ci = t.shape[0] // 2, t.shape[1] // 2
        if not np.all(np.isfinite(t)) or t[cj, ci] != 0 or t.min() < 0:
            raise ValueError("ArrayTip values must be finite, ≥ 0, and 0 at the centre (apex)")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "pixel_size", tuple(float(v) for v in self.pixel_size))


def mlct_tip(shape: str = "cone", apex_radius: float = MLCT_APEX_RADIUS,
             half_angle_deg: float = MLCT_HALF_ANGLE_DEG):
    """Bruker MLCT default tip: ``"cone"`` (spherical apex) or ``"paraboloid"``."""
    if shape == "cone":
        return ConeTip(apex_radius, half_angle_deg)
    if shape in ("paraboloid", "parabolic"):
        return ParabolicTip(apex_radius)
    raise ValueError(f"tip shape must be 'cone' or 'paraboloid', got {shape!r}")


def tip_array(tip, pixel_size, height_range: float | None = None, *, max_radius: float | None = None):
    """Sample a tip on a pixel grid, cropped to where it can matter.

    Parameters
    ----------
    tip : ParabolicTip | ConeTip | ArrayTip
    pixel_size : (dx, dy) [m]
        The sample's pixel pitch; the tip is point-sampled at offsets (i·dx, j·dy).
    height_range : float, optional
        Sample height range max(z) − min(z) [m]. Tip points higher than that above the apex can
        never touch the sample (the apex on the lowest point would already be higher), so the
        footprint is cropped to ``t ≤ height_range`` — exact, not an approximation.
    max_radius : float, optional
        Extra hard cap on the footprint radius [m] (e.g. the physical tip height's reach).

    Returns
    -------
    t : ndarray (2·nj+1, 2·ni+1)
        Tip heights [m] (apex = 0 at the centre).
    footprint : bool ndarray, same shape
        Offsets that take part in the dilation.
    """
    dx, dy = (float(v) for v in np.broadcast_to(np.asarray(pixel_size, float), (2,)))
    if isinstance(tip, ArrayTip):
        if not np.allclose(tip.pixel_size, (dx, dy), rtol=1e-9, atol=0.0):
            raise ValueError(f"ArrayTip sampled at {tip.pixel_size}, sample pixels are {(dx, dy)}")
        t = tip.t
        fp = np.ones(t.shape, bool) if height_range is None else t <= height_range
        return t, fp
    h = np.inf if height_range is None else max(float(height_range), 0.0)
    rmax = np.inf if max_radius is None else float(max_radius)
    r = min(tip.radius_at_height(h) if np.isfinite(h) else np.inf, rmax)
    if not np.isfinite(r):
        raise ValueError("give height_range or max_radius to bound the tip footprint")
    ni, nj = int(np.floor(r / dx + 1e-9)), int(np.floor(r / dy + 1e-9))
    X, Y = np.meshgrid(dx * np.arange(-ni, ni + 1), dy * np.arange(-nj, nj + 1))
    t = tip.height(X, Y)
    fp = (np.hypot(X, Y) <= r * (1 + 1e-12)) & (t <= h)
    return t, fp
