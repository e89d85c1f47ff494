"""Feedforward compensation: turning the intended XY trajectory into drive voltages."""

from .controllers import CONTROLLER_NAMES, NominalLinear, VendorLinearisation, build_controller

__all__ = ["CONTROLLER_NAMES", "NominalLinear", "VendorLinearisation", "build_controller"]
