"""The real instrument's raster as afmsim geometry, and the twin's sample estimate from a measured trace.

A real scan of ``pixels`` × ``lines`` over ``size_m`` at ``line_time_s`` per direction becomes an
afmsim :class:`~afmsim.scan.RasterGeometry` whose lines are widened by the instrument's overscan
(``overscan_fraction`` of the image width in all, half at each end, rounded to whole pixels) and
centred at ``centre_fraction`` of the fast axis' travel; the image is the middle ``pixels`` of each
line. The line rate follows afmsim's convention (one line = trace + retrace):
``1 / (2 · line_time_s)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import interp1d

from afmsim.samples import HeightMap
from afmsim.scan import RasterGeometry

__all__ = ["RealScan", "twin_geometry", "image_columns", "sample_from_trace"]


@dataclass(frozen=True)
class RealScan:
    """What a vendor file says about one scan (SI units)."""

    size_m: tuple[float, float]
    pixels: int
    lines: int
    line_time_s: float


def _overscan_pixels(scan: RealScan, overscan_fraction: float) -> int:
    return int(round(0.5 * overscan_fraction * scan.pixels))


def twin_geometry(scan: RealScan, travel_m: float, overscan_fraction: float, centre_fraction: float,
                  samples_per_pixel: int = 4, lines: int | None = None) -> RasterGeometry:
    """afmsim raster for ``scan`` on a fast axis of ``travel_m``; ``lines`` overrides the line count."""
    extra = _overscan_pixels(scan, overscan_fraction)
    dx, dy = scan.size_m[0] / scan.pixels, scan.size_m[1] / scan.lines
    width = (scan.pixels + 2 * extra) * dx
    offset_x = centre_fraction * travel_m - width / 2
    offset_y = max(centre_fraction * travel_m - scan.size_m[1] / 2, 0.0)
    if offset_x < 0:
        raise ValueError(f"a {width * 1e6:.3g} µm line (overscan included) does not fit the twin's "
                         f"{travel_m * 1e6:.3g} µm travel at centre_fraction {centre_fraction:g}")
    n_lines = scan.lines if lines is None else lines
    return RasterGeometry(size=(width, n_lines * dy), offset=(offset_x, offset_y), pixels=scan.pixels + 2 * extra,
                          lines=n_lines, line_rate_hz=1.0 / (2.0 * scan.line_time_s), samples_per_pixel=samples_per_pixel)


def image_columns(geometry: RasterGeometry, scan: RealScan) -> slice:
    """The columns of a twin image (overscan included) that make the real image."""
    extra = (geometry.pixels - scan.pixels) // 2
    return slice(extra, extra + scan.pixels)


def sample_from_trace(trace: np.ndarray, x_trace: np.ndarray, y_lines: np.ndarray, pixel_m: float,
                      margin_m: float) -> HeightMap:
    """The sample estimate: the measured trace placed where the twin says the tip was.

    ``trace`` (lines, pixels) heights (m); ``x_trace`` (lines, pixels) the twin's actual x of each
    trace pixel; ``y_lines`` (lines,) the twin's actual y of each line. Each row is resampled onto a
    regular x grid of ``pixel_m`` (edge values held beyond the data), then each column onto a
    regular y grid, covering the data plus ``margin_m`` on every side.
    """
    x0, x1 = float(np.min(x_trace)) - margin_m, float(np.max(x_trace)) + margin_m
    y_order = np.argsort(y_lines)
    ys = np.asarray(y_lines, dtype=np.float64)[y_order]
    dy = float(np.median(np.diff(ys))) if ys.size > 1 else pixel_m
    y0, y1 = ys[0] - margin_m, ys[-1] + margin_m
    gx = np.arange(x0, x1 + pixel_m, pixel_m)
    gy = np.arange(y0, y1 + dy, dy)
    rows = np.empty((trace.shape[0], gx.size))
    for k, j in enumerate(y_order):
        order = np.argsort(x_trace[j])
        rows[k] = np.interp(gx, x_trace[j][order], trace[j][order])
    if ys.size > 1:
        z = interp1d(ys, rows, axis=0, bounds_error=False, fill_value=(rows[0], rows[-1]), assume_sorted=True)(gy)
    else:
        z = np.repeat(rows, gy.size, axis=0)
    return HeightMap(z, (pixel_m, dy), (gx[0], gy[0]))
