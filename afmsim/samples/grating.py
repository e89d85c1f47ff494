"""HS-500MG calibration grating (Innovative Solutions Bulgaria): analytic height maps.

Datasheet row "HS-500MG" (M confidence): SiO₂ on Si, 500 nm ± 3 % steps; lines in X and Y and
circular pillars/holes at 5 µm pitch; squares at 10 µm pitch; ~50 % duty cycle. The sidewall angle
is *not published* (row "grating sidewall", **L confidence**: 50–70° wet-etched, 80–90° dry-etched);
the default 80° is a scenario parameter. Reference paper (Wang et al. 2015, §3.4): 500 nm high,
5 µm period lines, scanned so the fast x scan crosses them.

Profile of one line (``pattern="lines"``, lines run along y, so z depends on x only):
a trapezoid of height ``h``; its width *at mid-height* is ``duty_cycle·period``; each sidewall
spans ``w = h / tan(sidewall_angle)`` horizontally (w = 0 for 90°). The map is the exact **pixel
average** of that profile over each pixel's x extent (box-filter anti-aliasing, so vertical walls
give one intermediate pixel per edge and the mean height is exactly ``h·duty_cycle``).
Heights: 0 on the floor, ``height`` on the line tops.

2-D variants (point-sampled with ``supersample²`` sub-pixels per pixel): ``"squares"`` (square
frusta, side ``duty·period`` at mid-height, 10 µm pitch on the real chip), ``"pillars"`` (circular
frusta of mid-height diameter ``duty·period``), ``"holes"`` (the negative of pillars).
"""

from __future__ import annotations

import numpy as np

from .heightmap import HeightMap
from .raycast import pixel_grid

__all__ = ["grating_heightmap", "grating_profile"]

PATTERNS = ("lines", "squares", "pillars", "holes")


def _ramp_antiderivative(s, w):
    """F(s) = ∫_{-∞}^{s} g(u) du for the unit ramp g(u) = clip(0.5 + u/w, 0, 1) (step if w = 0)."""
    s = np.asarray(s, float)
    if w <= 0:
        return np.maximum(s, 0.0)
    return np.where(s < -w / 2, 0.0, np.where(s > w / 2, s, (s + w / 2) ** 2 / (2 * w)))


def _ramp(s, w):
    s = np.asarray(s, float)
    if w <= 0:
        return (s >= 0).astype(float)
    return np.clip(0.5 + s / w, 0.0, 1.0)


def _line_profile(x, period, duty, w, height, x0, pixel_width):
    """Height of the periodic line profile at x (pixel-averaged over ``pixel_width`` if > 0)."""
    L = duty * period
    u = np.mod(np.asarray(x, float) - x0 + period / 2, period) - period / 2  # ∈ [-P/2, P/2)
    z = np.zeros_like(u)
    for n in (-1, 0, 1):  # neighbouring periods (ramps reach at most P/2 + pixel/2 away)
        un = u - n * period
        if pixel_width > 0:
            hw = pixel_width / 2
            G = lambda s: (_ramp_antiderivative(s + hw, w) - _ramp_antiderivative(s - hw, w)) / pixel_width
        else:
            G = lambda s: _ramp(s, w)
        z += G(un + L / 2) - G(un - L / 2)  # rising edge at -L/2, falling edge at +L/2
    return height * z


def _check(period, height, duty_cycle, sidewall_angle_deg):
    if not (period > 0 and height > 0):
        raise ValueError(f"period and height must be > 0, got {period}, {height}")
    if not (0 < duty_cycle < 1):
        raise ValueError(f"duty_cycle must be in (0, 1), got {duty_cycle}")
    if not (0 < sidewall_angle_deg <= 90):
        raise ValueError(f"sidewall_angle_deg must be in (0, 90], got {sidewall_angle_deg}")
    w = 0.0 if sidewall_angle_deg >= 90 else height / np.tan(np.radians(sidewall_angle_deg))
    L = duty_cycle * period
    if w > min(L, period - L) * (1 + 1e-12):
        raise ValueError(
            f"sidewalls too shallow: each spans {w:.3g} m horizontally, more than the line "
            f"({L:.3g} m) or gap ({period - L:.3g} m) width at mid-height; raise the angle or change duty_cycle")
    return w


def grating_profile(x, *, period=5e-6, height=500e-9, duty_cycle=0.5, sidewall_angle_deg=80.0,
                    x0=0.0, pixel_width=0.0) -> np.ndarray:
    """1-D line-grating height [m] at positions ``x`` [m]; a line is centred at ``x0``.

    ``pixel_width`` > 0 returns the average over [x − pw/2, x + pw/2] (exact box filter).
    """
    w = _check(period, height, duty_cycle, sidewall_angle_deg)
    return _line_profile(x, period, duty_cycle, w, height, x0, pixel_width)


def grating_heightmap(
    shape=(256, 256),
    extent=(20e-6, 20e-6),
    *,
    pixel_size=None,
    origin=None,
    center=(0.0, 0.0),
    pattern: str = "lines",
    period: float | None = None,
    height: float = 500e-9,
    duty_cycle: float = 0.5,
    sidewall_angle_deg: float = 80.0,
    lines_along: str = "y",
    phase: tuple[float, float] = (0.0, 0.0),
    supersample: int = 4,
) -> HeightMap:
    """HS-500MG-like grating height map.

    Parameters
    ----------
    shape : (ny, nx)
        Pixels.
    extent, pixel_size, origin, center
        Grid in metres (see :func:`afmsim.samples.raycast.pixel_grid`); default 20 µm × 20 µm
        centred on (0, 0).
    pattern : {"lines", "squares", "pillars", "holes"}
    period : float, optional
        Pitch [m]. Default 5 µm (lines, pillars, holes) or 10 µm (squares) — datasheet, M.
    height : float
        Step height [m]. Default 500 nm (datasheet ±3 %, M).
    duty_cycle : float
        Feature width at mid-height / period, in (0, 1). Default 0.5 (datasheet "~50 %", M).
    sidewall_angle_deg : float
        Sidewall angle from the horizontal, (0, 90]. Default 80° (not published: L confidence).
    lines_along : {"y", "x"}
        For ``"lines"``: direction the lines run. "y" (default): z varies along x, so the fast x
        scan crosses the lines.
    phase : (float, float)
        Position [m] of a feature centre (a line centre / pillar centre). Default (0, 0).
    supersample : int
        Sub-pixels per axis for the 2-D patterns (lines are exactly box-filtered instead).
    """
    if pattern not in PATTERNS:
        raise ValueError(f"pattern must be one of {PATTERNS}, got {pattern!r}")
    if lines_along not in ("x", "y"):
        raise ValueError(f"lines_along must be 'x' or 'y', got {lines_along!r}")
    if period is None:
        period = 10e-6 if pattern == "squares" else 5e-6
    w = _check(period, height, duty_cycle, sidewall_angle_deg)
    if extent is not None and pixel_size is not None:
        extent = None
    (dx, dy), org = pixel_grid(shape, extent, pixel_size=pixel_size, origin=origin,
                               center=None if origin is not None else center)
    ny, nx = (int(v) for v in shape)
    x = org[0] + dx * np.arange(nx)
    y = org[1] + dy * np.arange(ny)
    px, py = phase

    if pattern == "lines":
        if lines_along == "y":
            prof = _line_profile(x, period, duty_cycle, w, height, px, dx)
            z = np.broadcast_to(prof[None, :], (ny, nx))
        else:
            prof = _line_profile(y, period, duty_cycle, w, height, py, dy)
            z = np.broadcast_to(prof[:, None], (ny, nx))
        return HeightMap(np.array(z), (dx, dy), org)

    k = max(1, int(supersample))
    sub = (np.arange(k) + 0.5) / k - 0.5
    xs = (x[:, None] + sub[None, :] * dx).ravel()  # (nx·k,)
    ys = (y[:, None] + sub[None, :] * dy).ravel()
    if pattern == "squares":
        zx = _line_profile(xs, period, duty_cycle, w, 1.0, px, 0.0)
        zy = _line_profile(ys, period, duty_cycle, w, 1.0, py, 0.0)
        zz = height * np.minimum(zy[:, None], zx[None, :])  # frustum = intersection of line sets
    else:
        ux = np.mod(xs - px + period / 2, period) - period / 2
        uy = np.mod(ys - py + period / 2, period) - period / 2
        r = np.hypot(uy[:, None], ux[None, :])
        zz = height * _ramp(duty_cycle * period / 2 - r, w)
        if pattern == "holes":
            zz = height - zz
    z = zz.reshape(ny, k, nx, k).mean(axis=(1, 3))
    return HeightMap(z, (dx, dy), org)
