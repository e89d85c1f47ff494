"""One raster scan: controller → hysteretic XY stage → tip on the dilated surface → Z loop → images."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from afmsim.samples.heightmap import HeightMap

from .trajectory import RasterTrajectory
from .zloop import ZFeedback, ZStage, track_surface

__all__ = ["ScanImages", "scan_frame", "surface_under_tip"]


@dataclass(frozen=True)
class ScanImages:
    """The recorded trace and retrace images and where the tip really was.

    ``trace`` and ``retrace`` hold recorded heights (m) at the *intended* pixel positions, both
    left → right. ``actual_x_trace``/``actual_x_retrace`` give the mean actual x (m) of the tip
    over each pixel, the ground truth behind the image distortion.
    """

    trace: HeightMap
    retrace: HeightMap
    actual_x_trace: np.ndarray
    actual_x_retrace: np.ndarray


def surface_under_tip(surface: HeightMap, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """Dilated surface height (m) at actual tip positions, bilinear between pixel centres.

    Positions outside the map read the nearest edge pixel; callers size the map with a margin
    that covers the stage's excursions.
    """
    rows = (np.asarray(y_m) - surface.origin[1]) / surface.pixel_size[1]
    cols = (np.asarray(x_m) - surface.origin[0]) / surface.pixel_size[0]
    return map_coordinates(surface.z, [rows, cols], order=1, mode="nearest")


def scan_frame(surface: HeightMap, trajectory: RasterTrajectory, stage, controller_x, controller_y,
               z_stage: ZStage, z_feedback: ZFeedback, rng: np.random.Generator) -> ScanImages:
    """Scan the tip-dilated ``surface`` along ``trajectory`` through ``stage`` with feedforward.

    ``controller_x/y.predict(displacement) -> voltage`` turn the intended displacement of each axis
    into drive voltages; ``stage.move(t, vx, vy) -> (x, y)`` gives the actual positions.
    """
    vx = controller_x.predict(trajectory.x)
    vy = controller_y.predict(trajectory.y)
    x_actual, y_actual = stage.move(trajectory.t, vx, vy)
    heights = track_surface(surface_under_tip(surface, x_actual, y_actual), trajectory.geometry.sample_rate_hz,
                            z_stage, z_feedback, rng)
    trace, retrace = trajectory.to_images(heights)
    ax_trace, ax_retrace = trajectory.to_images(x_actual)
    g = trajectory.geometry
    origin = (g.pixel_centres_x[0], g.line_centres_y[0])
    return ScanImages(HeightMap(trace, g.pixel_size, origin), HeightMap(retrace, g.pixel_size, origin),
                      ax_trace, ax_retrace)
