"""The desired (intended) raster trajectory of the XY stage and its pixel bookkeeping.

Conventions (pinned by tests):

* the fast axis is X; each line is a **trace** (left → right, +x) followed by a **retrace**
  (right → left), a symmetric triangle at the line rate (one trace + one retrace per line period);
* the slow axis is Y; it steps by one line pitch at the start of each trace (a staircase, so
  trace and retrace of a line share one intended y), lines ordered along +y;
* before the first line the stage is driven from rest (0 V, de-energised) to the scan start along
  a cosine ramp and held there (``approach_s``), as a real instrument does when it moves to the
  scan origin; the controllers see the same history, so their models start from eq. (4);
* every sample belongs to one pixel of one half-line: ``pixel`` index 0…nx−1 counted in the
  intended position (so retrace samples are stored at the pixel they were *meant* to visit),
  which is how hysteresis becomes image shift and distortion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["RasterGeometry", "RasterTrajectory", "raster_trajectory"]


@dataclass(frozen=True)
class RasterGeometry:
    """Scan geometry and timing, SI units.

    Attributes
    ----------
    size : (float, float)
        Scan size (width along x, height along y), metres.
    offset : (float, float)
        Stage displacement (x, y) of the scan's first pixel edge (lower-left corner), metres,
        measured from the de-energised stage position.
    pixels, lines : int
        Pixels per line (x) and number of lines (y).
    line_rate_hz : float
        Lines per second; one line = trace + retrace.
    samples_per_pixel : int
        Time samples per pixel and half-line (numerical knob: the Z loop runs at this rate).
    approach_s : float
        Duration of the move from rest to the scan start plus settling, seconds.
    """

    size: tuple[float, float]
    offset: tuple[float, float]
    pixels: int
    lines: int
    line_rate_hz: float = 1.0
    samples_per_pixel: int = 4
    approach_s: float = 1.0

    @property
    def pixel_size(self) -> tuple[float, float]:
        """(dx, dy) in metres."""
        return (self.size[0] / self.pixels, self.size[1] / self.lines)

    @property
    def sample_rate_hz(self) -> float:
        """Time samples per second during the frame."""
        return 2 * self.pixels * self.samples_per_pixel * self.line_rate_hz

    @property
    def pixel_centres_x(self) -> np.ndarray:
        """Intended x of the pixel centres, metres (stage coordinates)."""
        return self.offset[0] + (np.arange(self.pixels) + 0.5) * self.pixel_size[0]

    @property
    def line_centres_y(self) -> np.ndarray:
        """Intended y of the lines, metres (stage coordinates)."""
        return self.offset[1] + (np.arange(self.lines) + 0.5) * self.pixel_size[1]


@dataclass(frozen=True)
class RasterTrajectory:
    """Desired stage displacement over time; the frame part maps onto image pixels.

    ``t``, ``x``, ``y`` cover approach + frame. ``frame_start`` is the index of the first frame
    sample; frame samples are ordered (line, half, pixel, sub-sample) with half 0 = trace and
    half 1 = retrace, so ``values[frame_start:].reshape(lines, 2, pixels, samples_per_pixel)``
    groups them by pixel (retrace pixels in the order visited, i.e. right to left).
    """

    geometry: RasterGeometry
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    frame_start: int

    def to_images(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Average per-sample ``values`` over each pixel → (trace, retrace) images (lines, pixels).

        Both images are returned left → right (the retrace is re-ordered to intended x).
        """
        g = self.geometry
        frame = np.asarray(values, dtype=np.float64)[self.frame_start:].reshape(g.lines, 2, g.pixels, g.samples_per_pixel)
        # a running sum over the sub-samples: numpy's mean over a short last axis is ~4× slower
        per_pixel = frame[..., 0].copy()
        for k in range(1, g.samples_per_pixel):
            per_pixel += frame[..., k]
        per_pixel /= g.samples_per_pixel
        return per_pixel[:, 0, :], per_pixel[:, 1, ::-1]


def raster_trajectory(geometry: RasterGeometry) -> RasterTrajectory:
    """Build the intended trajectory for a raster scan (see module docstring for conventions)."""
    g = geometry
    dx, dy = g.pixel_size
    spp = g.samples_per_pixel
    dt = 1.0 / g.sample_rate_hz

    # Frame: sample k of a half-line sits at the centre of its sub-interval, so pixel p of the trace
    # is visited over [offset + p·dx, offset + (p+1)·dx) and its samples average to the pixel centre.
    along = (np.arange(g.pixels * spp) + 0.5) / spp * dx
    trace = g.offset[0] + along
    retrace = g.offset[0] + g.size[0] - along
    x_frame = np.tile(np.concatenate([trace, retrace]), g.lines)
    y_frame = np.repeat(g.line_centres_y, 2 * g.pixels * spp)

    # Approach: a cosine ramp from rest to the first frame sample over the first half of approach_s,
    # then a hold; sampled at the frame rate so the whole record has one time step.
    n_approach = max(int(round(g.approach_s / dt)), 2)
    n_ramp = n_approach // 2
    ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(n_ramp) / (n_ramp - 1 if n_ramp > 1 else 1))
    shape = np.concatenate([ramp, np.ones(n_approach - n_ramp)])
    x = np.concatenate([shape * x_frame[0], x_frame])
    y = np.concatenate([shape * y_frame[0], y_frame])
    t = np.arange(x.size) * dt
    return RasterTrajectory(g, t, x, y, n_approach)
