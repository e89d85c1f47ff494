"""The instrument's time loop: raster trajectory, XY feedforward through the stage, Z feedback."""

from .raster import ScanImages, scan_frame, surface_under_tip
from .trajectory import RasterGeometry, RasterTrajectory, raster_trajectory
from .zloop import ZFeedback, ZStage, track_surface

__all__ = ["RasterGeometry", "RasterTrajectory", "raster_trajectory", "ScanImages", "scan_frame",
           "surface_under_tip", "ZFeedback", "ZStage", "track_surface"]
