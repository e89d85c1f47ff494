"""Predict a real scan's trace/retrace disagreement on a twin, and on afmsim's default stage for comparison.

The measured trace is the sample estimate; the scan (size, pixels, lines, line time from the file) is
simulated by :func:`afmsim.twin.simulate.simulate_scan`; the simulated retrace's shift profile and
NSL2 (paper eq. 8, :func:`afmsim.metrics.nsl2_binarized`) are compared with the measured ones.

The height noise of the simulated scan is that scan's own, measured on the flattest parts of the
file's trace (:func:`afmsim.diagnosis.engine.flattest_noise`; the retrace is never looked at), not the
calibration file's: it belongs to the scan (sample, Z range, gains) more than to the head. The same
head (scan head 75-16-106) shows 4.6 nm on ``test.nid`` and 0.03 nm on nsfopen's ``MoS2.nid``; with
the calibration file's noise the twin overstated MoS2's NSL2 by +320 %.
"""

from __future__ import annotations

import numpy as np

from afmsim.diagnosis.engine import flattest_noise
from afmsim.metrics import nsl2_binarized
from afmsim.scan import ZFeedback
from afmsim.stage import default_stage

from .instrument import Instrument, build_twin_stage, twin_z_feedback
from .raster import RealScan
from .shift_profile import shift_profile
from .simulate import simulate_scan

__all__ = ["predict_images", "REPORT_WINDOWS"]

REPORT_WINDOWS = 8
"""Windows across the fast axis in ``prediction.json``."""


def _rms(a) -> float:
    a = np.asarray(a, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a * a))) if a.size else float("nan")


def _simulated(stage, z_feedback, trace, scan, instrument: Instrument, travel_m: float, seed: int):
    habit = instrument.scan
    sim_trace, sim_retrace = simulate_scan(stage, z_feedback, trace, scan, travel_m=travel_m,
                                           overscan_fraction=habit.overscan_fraction,
                                           centre_fraction=habit.centre_fraction,
                                           samples_per_pixel=habit.samples_per_pixel,
                                           rng=np.random.default_rng(seed))
    profile = shift_profile(sim_trace, sim_retrace, scan.size_m[0] / scan.pixels, REPORT_WINDOWS)
    return sim_trace, sim_retrace, profile, nsl2_binarized(sim_trace, sim_retrace)


def predict_images(instrument: Instrument, trace, retrace, scan: RealScan, *, seed: int = 0) -> tuple[dict, dict]:
    """``(prediction, arrays)``: the ``prediction.json`` content and the images/profiles for the figure.

    The default-stage prediction uses afmsim's default stage and Z loop with the same raster habit
    (overscan, image centred in the travel) and the same height noise as the twin, so only the
    instrument differs.
    """
    trace = np.asarray(trace, dtype=np.float64)
    retrace = np.asarray(retrace, dtype=np.float64)
    dx = scan.size_m[0] / scan.pixels
    measured = shift_profile(trace, retrace, dx, REPORT_WINDOWS)
    measured_nsl2 = nsl2_binarized(trace, retrace)
    noise_m = flattest_noise((trace,))
    noise_from = "this file's trace (flattest parts)"
    if not np.isfinite(noise_m):  # lines shorter than a noise window
        noise_m, noise_from = instrument.z_loop.height_noise_nm * 1e-9, "the instrument (lines too short to measure)"
    noise_m = min(noise_m, 100e-9)
    scan_instrument = instrument.model_copy(update={"z_loop": instrument.z_loop.model_copy(
        update={"height_noise_nm": noise_m * 1e9})})
    twin = _simulated(build_twin_stage(scan_instrument), twin_z_feedback(scan_instrument), trace, scan, scan_instrument,
                      scan_instrument.fast_axis.travel_um * 1e-6, seed)
    stock = default_stage()
    stock_travel_m = stock.x.params.sensitivity_m_per_V * stock.x.params.hysteresis.calibration_amplitude_V
    try:
        default = _simulated(stock, ZFeedback(deflection_noise_m=noise_m), trace, scan, scan_instrument, stock_travel_m, seed)
    except ValueError as error:  # the scan does not fit the default stage's travel
        default = error
    measured_rms = _rms(measured.shift_m)

    def scored(result) -> dict:
        _, _, profile, nsl2 = result
        error = _rms(profile.shift_m - measured.shift_m)
        return {"predicted_shift_m": profile.shift_m, "rms_error_m": error,
                "rms_error_over_measured_rms": error / measured_rms if measured_rms > 0 else None,
                "nsl2": {"measured": measured_nsl2, "predicted": nsl2},
                "nsl2_relative_error": (nsl2 - measured_nsl2) / measured_nsl2 if measured_nsl2 > 0 else None}

    twin_scores = scored(twin)
    if isinstance(default, ValueError):
        default_scores = {"predicted_shift_m": None, "rms_error_m": None, "nsl2": None,
                          "not_predicted": f"afmsim's default stage cannot scan this: {default}"}
        default = (None, None, None, None)
    else:
        default_scores = scored(default)
    prediction = {
        "x_m": measured.x_m, "measured_shift_m": measured.shift_m, "measured_shift_stderr_m": measured.stderr_m,
        "measured_rms_m": measured_rms, **twin_scores,
        "predicted_over_default_rms_error": (twin_scores["rms_error_m"] / default_scores["rms_error_m"]
                                             if default_scores["rms_error_m"] else None),
        "default_stage": default_scores,
        "height_noise_m": noise_m, "height_noise_from": noise_from,
        "scan": {"size_m": scan.size_m, "pixels": scan.pixels, "lines": scan.lines, "line_time_s": scan.line_time_s},
        "seed": seed,
        "sign": "shift = x_retrace - x_trace of a feature; negative when the retrace shows it to the left",
    }
    arrays = {"trace": trace, "retrace": retrace, "twin_trace": twin[0], "twin_retrace": twin[1],
              "default_retrace": default[1], "measured_profile": measured, "twin_profile": twin[2],
              "default_profile": default[2]}
    return prediction, arrays
