"""Simulate a real scan on a twin: the measured trace as the sample, afmsim's raster, stage and Z loop.

Two forms of the same simulation:

* :func:`simulate_scan` — the full scan through :func:`afmsim.scan.scan_frame` (XY plant, Z loop,
  every line): what ``afmsim predict`` reports.
* :func:`fast_pair` — the calibration's inner loop: the fast axis alone is run for a few lines to
  its periodic state, its last line's trace/retrace positions are applied to every measured line,
  and the Z loop is a first-order lag of time constant ``lag_s`` on the recorded height. It leaves
  out what changes from line to line (creep and drift over the frame, slow-axis motion, the Z
  stage's hysteresis); :func:`simulate_scan` keeps them.

In both, the sample estimate is the measured trace placed where the twin says the tip was on the
trace (:func:`afmsim.twin.raster.sample_from_trace`), so a twin reproduces the measured trace by
construction and everything it predicts is in the retrace.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.signal import lfilter, lfilter_zi

from afmsim.compensation import NominalLinear
from afmsim.scan import ZFeedback, ZStage, raster_trajectory, scan_frame
from afmsim.stage import PiezoAxis, XYStage

from .raster import RealScan, image_columns, sample_from_trace, twin_geometry

__all__ = ["simulate_scan", "fast_pair", "WARM_LINES"]

WARM_LINES = 4
"""Lines the fast axis runs before the one :func:`fast_pair` uses (its loop is periodic by then)."""


def simulate_scan(stage: XYStage, z_feedback: ZFeedback, trace: np.ndarray, scan: RealScan, *, travel_m: float,
                  overscan_fraction: float, centre_fraction: float, samples_per_pixel: int,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(trace, retrace) images (lines, pixels) of ``scan`` simulated on ``stage`` with ``z_feedback``.

    ``trace`` (lines, pixels, m) is the measured trace, the sample estimate. Drive: the nominal linear
    sensitivity of each axis (the open-loop raster). The Z stage is linear: the real Z stage's
    hysteresis is already in the measured trace that serves as the sample (a hysteretic twin Z
    stage would apply it twice and drift the recorded height by ~0.1 µm over a tilted frame).
    """
    geometry = twin_geometry(scan, travel_m, overscan_fraction, centre_fraction, samples_per_pixel)
    trajectory = raster_trajectory(geometry)
    controllers = [NominalLinear(axis.params.sensitivity_m_per_V) for axis in (stage.x, stage.y)]
    x, y = stage.move(trajectory.t, controllers[0].predict(trajectory.x), controllers[1].predict(trajectory.y))
    x_trace, _ = trajectory.to_images(x)      # the twin's actual position of each trace pixel
    y_trace, _ = trajectory.to_images(y)
    columns = image_columns(geometry, scan)
    dx = scan.size_m[0] / scan.pixels
    surface = sample_from_trace(trace, x_trace[:, columns], y_trace[:, columns].mean(axis=1), dx / 2,
                                margin_m=0.05 * geometry.size[0] + 5 * dx)
    images = scan_frame(surface, trajectory, stage, *controllers, ZStage(hysteresis=False), z_feedback, rng,
                        positions=(x, y))
    return images.trace.z[:, columns], images.retrace.z[:, columns]


CREEP_REFERENCE = 0.02
"""γ (per decade) of the one creep bank :func:`fast_pair` discretises; other γ are interpolated."""


def _move_linear_in_creep(axis: PiezoAxis, t, v) -> np.ndarray:
    """``axis.move(t, v)``, with the creep bank's γ dependence taken as exactly linear.

    The bank's weights are the least-squares fit of ``1 + γ·log10(t/t_ref)`` (:func:`afmsim.stage.creep_bank`),
    linear in γ while no weight sits at its bound, so the response is ``x(0) + γ/γ_ref·(x(γ_ref) − x(0))``
    (checked: within 0.03 nm of the direct result on a 4 V triangle at γ up to 0.08). The calibration
    varies γ at every step, and discretising a new bank costs ~0.1 s; this costs one more hysteresis run.
    """
    p = axis.params
    if not (p.creep_enabled and p.creep_gamma > 0):
        return axis.move(t, v)
    without = PiezoAxis(replace(p, creep_enabled=False)).move(t, v)
    reference = PiezoAxis(replace(p, creep_gamma=CREEP_REFERENCE)).move(t, v)
    reference -= without
    reference *= p.creep_gamma / CREEP_REFERENCE
    return without + reference


def _branch_samples(axis: PiezoAxis, scan: RealScan, travel_m: float, overscan_fraction: float,
                    centre_fraction: float, samples_per_pixel: int):
    geometry = twin_geometry(scan, travel_m, overscan_fraction, centre_fraction, samples_per_pixel, lines=WARM_LINES)
    trajectory = raster_trajectory(geometry)
    x = _move_linear_in_creep(axis, trajectory.t, trajectory.x / axis.params.sensitivity_m_per_V)
    last = x[trajectory.frame_start:].reshape(geometry.lines, 2, geometry.pixels * samples_per_pixel)[-1]
    return geometry, last[0], last[1], 1.0 / geometry.sample_rate_hz


def fast_pair(axis: PiezoAxis, trace: np.ndarray, scan: RealScan, *, travel_m: float, overscan_fraction: float,
              centre_fraction: float, lag_s: float, samples_per_pixel: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """(trace, retrace) images of ``scan`` on the fast ``axis`` alone, Z loop as a first-order lag (s).

    Every line uses the fast axis' periodic trace/retrace positions (see the module docstring).
    """
    geometry, x_up, x_down, dt = _branch_samples(axis, scan, travel_m, overscan_fraction, centre_fraction,
                                                 samples_per_pixel)
    spp = samples_per_pixel
    columns = image_columns(geometry, scan)
    pixel_x = x_up.reshape(geometry.pixels, spp).mean(axis=1)[columns]
    order = np.argsort(pixel_x)
    positions = np.concatenate([x_up, x_down])  # one line in time order: trace, then retrace
    index = np.clip(np.searchsorted(pixel_x[order], positions) - 1, 0, pixel_x.size - 2)
    left, right = pixel_x[order][index], pixel_x[order][index + 1]
    weight = np.clip((positions - left) / (right - left), 0.0, 1.0)
    t = np.asarray(trace, dtype=np.float64)[:, order]
    heights = t[:, index] * (1.0 - weight) + t[:, index + 1] * weight
    if lag_s > 0:
        pole = np.exp(-dt / lag_s)
        b, a = [1.0 - pole], [1.0, -pole]
        heights, _ = lfilter(b, a, heights, axis=1, zi=lfilter_zi(b, a)[None, :] * heights[:, :1])
    n = geometry.pixels
    per_pixel = heights.reshape(t.shape[0], 2, n, spp).mean(axis=3)
    return per_pixel[:, 0, columns], per_pixel[:, 1, ::-1][:, columns]
