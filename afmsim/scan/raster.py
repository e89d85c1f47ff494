"""One raster scan: controller → hysteretic XY stage → tip on the dilated surface → Z loop → images."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from afmsim.samples.heightmap import HeightMap

from .trajectory import RasterTrajectory
from .zloop import ZFeedback, ZStage, track_surface

__all__ = ["ScanImages", "scan_frame", "surface_under_tip"]


@dataclass(frozen=True)
class ScanImages:
    """The recorded trace and retrace images and where the tip really was.

    ``trace`` and ``retrace`` hold recorded heights (m) at the *intended* pixel positions, both
    left → right. ``actual_x_trace``/``actual_x_retrace`` give the mean actual x (m) of the tip
    over each pixel, the ground truth behind the image distortion. ``saturated`` counts the frame's
    time samples at which a drive sat at its amplifier limit: ``"x"``, ``"y"`` (XY drive clipped,
    :meth:`afmsim.stage.PiezoAxis.clipped`), ``"z"`` (Z loop pinned, :func:`track_surface`) and
    ``"any"`` (at least one of them); ``samples`` is the frame's number of time samples.
    ``error_trace``/``error_retrace`` (m, same pixels) are the Z loop's error signal, the measured
    deflection less the setpoint, as an AFM records its deflection (error) images (None when not
    recorded).
    """

    trace: HeightMap
    retrace: HeightMap
    actual_x_trace: np.ndarray
    actual_x_retrace: np.ndarray
    saturated: dict = field(default_factory=lambda: {"x": 0, "y": 0, "z": 0, "any": 0})
    samples: int = 0
    error_trace: np.ndarray | None = field(default=None, repr=False)
    error_retrace: np.ndarray | None = field(default=None, repr=False)

    @property
    def saturated_fraction(self) -> float:
        """Fraction of the frame's time samples with a drive at its limit (0 when none was counted)."""
        return self.saturated["any"] / self.samples if self.samples else 0.0


@njit(cache=True, nogil=True)
def _bilinear(z, x, y, x0, y0, dx, dy, out):  # pragma: no cover - compiled
    last_row, last_col = z.shape[0] - 1, z.shape[1] - 1
    for k in range(x.size):
        r = (y[k] - y0) / dy
        c = (x[k] - x0) / dx
        if r != r or c != c:  # NaN position: no index to read
            out[k] = np.nan
            continue
        r = min(max(r, 0.0), float(last_row))
        c = min(max(c, 0.0), float(last_col))
        i, j = int(r), int(c)
        i1, j1 = min(i + 1, last_row), min(j + 1, last_col)
        fr, fc = r - i, c - j
        out[k] = ((1.0 - fr) * ((1.0 - fc) * z[i, j] + fc * z[i, j1])
                  + fr * ((1.0 - fc) * z[i1, j] + fc * z[i1, j1]))


def surface_under_tip(surface: HeightMap, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """Dilated surface height (m) at actual tip positions, bilinear between pixel centres.

    Positions outside the map read the nearest edge pixel; callers size the map with a margin
    that covers the stage's excursions. Same values as ``scipy.ndimage.map_coordinates(order=1,
    mode="nearest")`` to rounding, compiled (numba) because the scan asks for 10⁶–10⁷ points and
    the general spline machinery costs ~5× more per point.
    """
    x, y = np.broadcast_arrays(np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64))
    out = np.empty(x.shape)
    _bilinear(np.ascontiguousarray(surface.z, dtype=np.float64), np.ascontiguousarray(x).ravel(),
              np.ascontiguousarray(y).ravel(), float(surface.origin[0]), float(surface.origin[1]),
              float(surface.pixel_size[0]), float(surface.pixel_size[1]), out.reshape(-1))
    return out


def scan_frame(surface: HeightMap, trajectory: RasterTrajectory, stage, controller_x, controller_y,
               z_stage: ZStage, z_feedback: ZFeedback, rng: np.random.Generator, *,
               positions: tuple[np.ndarray, np.ndarray] | None = None) -> ScanImages:
    """Scan the tip-dilated ``surface`` along ``trajectory`` through ``stage`` with feedforward.

    ``controller_x/y.predict(displacement) -> voltage`` turn the intended displacement of each axis
    into drive voltages; ``stage.move(t, vx, vy) -> (x, y)`` gives the actual positions (m), or
    ``positions`` where the caller has moved the stage with these drives already.
    """
    vx = controller_x.predict(trajectory.x)
    vy = controller_y.predict(trajectory.y)
    x_actual, y_actual = positions if positions is not None else stage.move(trajectory.t, vx, vy)
    z_limit = np.empty(trajectory.t.size, dtype=bool)
    error = np.empty(trajectory.t.size)
    heights = track_surface(surface_under_tip(surface, x_actual, y_actual), trajectory.geometry.sample_rate_hz,
                            z_stage, z_feedback, rng, at_limit=z_limit, error=error)
    trace, retrace = trajectory.to_images(heights)
    error_trace, error_retrace = trajectory.to_images(error)
    ax_trace, ax_retrace = trajectory.to_images(x_actual)
    g = trajectory.geometry
    origin = (g.pixel_centres_x[0], g.line_centres_y[0])
    frame = slice(trajectory.frame_start, None)
    limits = dict(zip("xyz", (*stage.clipped(vx[frame], vy[frame]), z_limit[frame])))
    saturated = {axis: int(np.count_nonzero(mask)) for axis, mask in limits.items()}
    saturated["any"] = int(np.count_nonzero(limits["x"] | limits["y"] | limits["z"]))
    return ScanImages(HeightMap(trace, g.pixel_size, origin), HeightMap(retrace, g.pixel_size, origin),
                      ax_trace, ax_retrace, saturated, int(z_limit[frame].size), error_trace, error_retrace)
