"""Calibrate a twin from one real forward/backward image pair.

What a trace/retrace pair constrains, and how it is fitted here:

* **Fast axis, trace vs retrace** (the displacement field between the two scan directions): the
  shift profile (:mod:`afmsim.twin.shift_profile`, 16 windows) of the measured pair is matched by
  the twin's (:func:`afmsim.twin.simulate.fast_pair`) through the fast axis' Preisach hysteretic
  fraction, relay-width scale and skew, its creep γ (at line rates creep acts as a rate-dependent
  hysteresis) and its drive lag (the amplifier's bandwidth: a lag τ moves every feature by
  −2·v·τ, a shift that is flat across the field, where hysteresis closes at the reversals), by
  weighted least squares (:func:`scipy.optimize.least_squares`,
  weights = each window's standard error) on up to 64 of the even lines, then refitted once against the measured
  profile minus the full scan's departure from ``fast_pair`` at the first optimum; the odd lines
  are held out and predicted by the full scan (:func:`afmsim.twin.simulate.simulate_scan`).
  Uncertainties: √diag((JᵀJ)⁻¹·max(1, χ²/dof)) at the optimum.
* **Z loop lag: not fitted.** A Z-loop lag and a drive lag both move features against the scan
  direction in proportion to the scan speed; one pair cannot tell them apart, so the twin puts the
  whole velocity-proportional shift into the drive lag (equivalent for predictions at any line
  rate) and the Z loop stays at the default (marked so). A slow contact-mode PI loop would also
  parachute on downhill edges, which the fast model leaves out.
* **Height noise**: the white noise of the flattest parts of the fitted lines of both directions
  (:func:`afmsim.diagnosis.engine.flattest_noise`: robust σ of second differences along x in
  32-pixel windows, their lowest tenth), not of the whole trace: a rough sample's pixel-scale
  structure is not instrument noise (``test.nid``: 6.6 nm over the whole trace, 4.6 nm on the
  flattest parts). ``afmsim predict`` takes the noise of the scan it predicts from that file's trace.
* **Slow axis**: the trace/retrace offset along y (whole-image registration) is reported; the
  slow axis' hysteresis is not constrained by one pair and stays at the default.
* **Absolute scale** (``pitch_m`` given): each direction's period along x against the known
  pitch, and its period per window over the image's (where that direction stretches or compresses
  the field); reported in ``calibration.json``, not fitted into the twin.

Everything else (drift, resonance, travel, where the image sits in the travel) is
not constrained by one image pair and stays at afmsim's default, marked ``default``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from afmsim.diagnosis.engine import flattest_noise
from afmsim.metrics import image_shift

from .instrument import Instrument, build_twin_stage, twin_z_feedback
from .raster import RealScan
from .shift_profile import shift_profile
from .simulate import fast_pair, simulate_scan

__all__ = ["ImageCalibration", "calibrate_images", "FIT_WINDOWS", "FITTED"]

FIT_WINDOWS = 16
"""Windows of the shift profile the fit matches (the reports use 8)."""

FITTED = {  # parameter -> (block, field, lower, upper, log-scaled in the fit, unit in the field name)
    "fast_axis.hysteretic_fraction": ("fast_axis", "hysteretic_fraction", 0.0, 1.0, False),
    "fast_axis.width_decay": ("fast_axis", "width_decay", 0.01, 5.0, True),
    "fast_axis.skew": ("fast_axis", "skew", -1.0, 1.0, False),
    "fast_axis.amplifier_bandwidth_hz": ("fast_axis", "amplifier_bandwidth_hz", 1.0, 1e5, True),
    "fast_axis.creep_gamma_per_decade": ("fast_axis", "creep_gamma_per_decade", 0.0, 0.1, False),
}

MAX_FIT_LINES = 64
"""Training lines the fit uses at most (evenly spread over the even lines): the median over more buys little."""


@dataclass(frozen=True)
class ImageCalibration:
    """The fitted instrument and what the fit found (values in the instrument's field units)."""

    instrument: Instrument
    values: dict
    uncertainties: dict
    correlation: np.ndarray
    measured_profile: object
    train_profile_rms_error_m: float
    facts: dict


def _with(instrument: Instrument, values: dict) -> Instrument:
    blocks = {}
    for key, value in values.items():
        block, field = FITTED[key][0], FITTED[key][1]
        blocks.setdefault(block, {})[field] = float(value)
    update = {block: getattr(instrument, block).model_copy(update=fields) for block, fields in blocks.items()}
    return instrument.model_copy(update=update)


def _to_theta(values: dict) -> np.ndarray:
    return np.array([np.log(values[k]) if FITTED[k][4] else values[k] for k in FITTED])


def _from_theta(theta) -> dict:
    return {k: float(np.exp(v) if FITTED[k][4] else v) for k, v in zip(FITTED, theta)}


def twin_profile(instrument: Instrument, trace, scan: RealScan, n_windows: int = FIT_WINDOWS):
    """The shift profile of ``scan`` simulated by :func:`fast_pair` on ``instrument``'s fast axis."""
    axis = build_twin_stage(instrument).x
    habit = instrument.scan
    lag_s = instrument.z_loop.lag_ms * 1e-3
    sim_trace, sim_retrace = fast_pair(axis, trace, scan, travel_m=instrument.fast_axis.travel_um * 1e-6,
                                       overscan_fraction=habit.overscan_fraction, centre_fraction=habit.centre_fraction,
                                       lag_s=lag_s, samples_per_pixel=habit.samples_per_pixel)
    return shift_profile(sim_trace, sim_retrace, scan.size_m[0] / scan.pixels, n_windows)


def _gradient_autocorrelation(g: np.ndarray) -> np.ndarray:
    seg = g - g.mean(axis=1, keepdims=True)
    spec = np.abs(np.fft.rfft(seg, n=2 * seg.shape[1], axis=1)) ** 2
    # divided by the overlap at each lag: unbiased, so a short window's peak does not drift to shorter lags
    return np.fft.irfft(spec.sum(axis=0))[: seg.shape[1]] / (seg.shape[1] - np.arange(seg.shape[1]))


def _peak_lag(ac: np.ndarray, lo: float, hi: float) -> float:
    """Sub-pixel lag (px) of the highest local maximum of ``ac`` in [lo, hi] px, NaN if none."""
    k = np.arange(1, ac.size - 1)
    inner = k[(ac[1:-1] > ac[:-2]) & (ac[1:-1] >= ac[2:]) & (k >= lo) & (k <= hi)]
    if inner.size == 0:
        return float("nan")
    k = inner[np.argmax(ac[inner])]
    left, mid, right = ac[k - 1], ac[k], ac[k + 1]
    curvature = left - 2 * mid + right
    return float(k + (0.5 * (left - right) / curvature if curvature < 0 else 0.0))


def local_period_m(image, pixel_size_m: float, pitch_m: float, n_windows: int = 4) -> tuple[float, np.ndarray]:
    """Period along x (m): of the whole image (strongest gradient-autocorrelation peak within ½–2× the
    pitch), and per window (the peak within ±30 % of the whole image's)."""
    g = np.gradient(np.asarray(image, dtype=np.float64), axis=1)
    whole = _peak_lag(_gradient_autocorrelation(g), 0.5 * pitch_m / pixel_size_m, 2 * pitch_m / pixel_size_m)
    edges = np.linspace(0, g.shape[1], n_windows + 1).round().astype(int)
    local = np.array([_peak_lag(_gradient_autocorrelation(g[:, a:b]), 0.7 * whole, 1.3 * whole)
                      for a, b in zip(edges[:-1], edges[1:])])
    return whole * pixel_size_m, local * pixel_size_m


JACOBIAN_STEPS = {"fast_axis.hysteretic_fraction": 0.01, "fast_axis.width_decay": 0.05, "fast_axis.skew": 0.05,
                  "fast_axis.amplifier_bandwidth_hz": 0.05, "fast_axis.creep_gamma_per_decade": 5e-4}
"""Central-difference steps for the uncertainties (θ units: log for the log-scaled parameters)."""


def _jacobian(residual, theta, lo, hi) -> np.ndarray:
    """Central differences of ``residual`` at ``theta`` with :data:`JACOBIAN_STEPS` (one-sided at a bound)."""
    columns = []
    for k, key in enumerate(FITTED):
        step = JACOBIAN_STEPS[key]
        up, down = theta.copy(), theta.copy()
        up[k], down[k] = min(theta[k] + step, hi[k]), max(theta[k] - step, lo[k])
        columns.append((residual(up) - residual(down)) / max(up[k] - down[k], 1e-12))
    return np.column_stack(columns)


def calibrate_images(trace, retrace, scan: RealScan, *, start: Instrument | None = None, pitch_m: float | None = None,
                     max_nfev: int = 60) -> ImageCalibration:
    """Fit the twin's fast-axis hysteresis to a measured pair (see the module docstring).

    ``start`` carries what is already known (header facts such as the overscan) and the defaults.
    """
    trace = np.asarray(trace, dtype=np.float64)
    retrace = np.asarray(retrace, dtype=np.float64)
    start = start or Instrument()
    dx = scan.size_m[0] / scan.pixels
    even = np.arange(0, trace.shape[0], 2)
    train = even[np.unique(np.linspace(0, even.size - 1, min(even.size, MAX_FIT_LINES)).round().astype(int))]
    measured = shift_profile(trace[train], retrace[train], dx, FIT_WINDOWS)
    usable = np.isfinite(measured.shift_m)
    if usable.sum() < 4:
        raise ValueError(f"only {int(usable.sum())} of {FIT_WINDOWS} windows show features in both trace and "
                         "retrace; the shift profile cannot be fitted (a flat or featureless scan?)")
    weight = 1.0 / np.maximum(measured.stderr_m[usable], 0.02 * dx)
    scan_train = RealScan(scan.size_m, scan.pixels, int(trace[train].shape[0]), scan.line_time_s)

    lo = _to_theta({k: FITTED[k][2] for k in FITTED})
    hi = _to_theta({k: FITTED[k][3] for k in FITTED})

    def fit(target, starts):
        def residual(theta):
            profile = twin_profile(_with(start, _from_theta(theta)), trace[train], scan_train)
            diff = profile.shift_m[usable] - target[usable]
            return np.where(np.isfinite(diff), diff, 5 * dx) * weight

        best = None
        if len(starts) > 2:  # refine the two starts that fit best as they are
            costs = [np.sum(residual(np.clip(_to_theta(v), lo + 1e-9, hi - 1e-9)) ** 2) for v in starts]
            starts = [starts[i] for i in np.argsort(costs)[:2]]
        for values in starts:
            found = least_squares(residual, np.clip(_to_theta(values), lo + 1e-9, hi - 1e-9), bounds=(lo, hi),
                                  x_scale="jac", diff_step=1e-3, max_nfev=max_nfev)
            if best is None or found.cost < best.cost:
                best = found
        return best, residual

    # starts: the measured mean shift as hysteresis (the default loop scaled to it), as a drive lag
    # (a lag τ moves every feature by −2·v·τ at scan speed v), and half of each
    default_profile = twin_profile(start, trace[train], scan_train)
    mean_shift = float(np.nanmean(measured.shift_m))
    ratio = mean_shift / np.nanmean(default_profile.shift_m)
    h0 = float(np.clip(start.fast_axis.hysteretic_fraction * ratio, 0.005, 0.9)) if np.isfinite(ratio) else 0.1
    speed = scan.size_m[0] / scan.line_time_s
    lag0 = max(-mean_shift, 0.1 * dx) / (2 * speed)
    bw_lag = float(np.clip(1 / (2 * np.pi * lag0), 2.0, 5e4))
    bw_default = start.fast_axis.amplifier_bandwidth_hz
    skew0, creep0 = start.fast_axis.skew, start.fast_axis.creep_gamma_per_decade
    keys = list(FITTED)
    starts = [dict(zip(keys, row)) for row in (
        (h0, 0.35, skew0, bw_default, creep0), (h0, 0.03, skew0, bw_default, creep0),
        (0.005, 0.35, skew0, bw_lag, 0.002), (h0 / 2, 0.03, skew0, 2 * bw_lag, creep0 / 2))]
    best, _ = fit(measured.shift_m, starts)
    # one correction for what fast_pair leaves out (line-to-line creep, slow axis, the PI Z loop):
    # refit against the measured profile minus the full scan's departure from fast_pair at the optimum
    first = _with(start, _from_theta(best.x))
    full_trace, full_retrace = simulate_scan(
        build_twin_stage(first), twin_z_feedback(first), trace[train], scan_train,
        travel_m=first.fast_axis.travel_um * 1e-6, overscan_fraction=first.scan.overscan_fraction,
        centre_fraction=first.scan.centre_fraction, samples_per_pixel=first.scan.samples_per_pixel,
        rng=np.random.default_rng(0))
    departure = (shift_profile(full_trace, full_retrace, dx, FIT_WINDOWS).shift_m
                 - twin_profile(first, trace[train], scan_train).shift_m)
    departure = np.where(np.isfinite(departure), departure, 0.0)
    best, residual = fit(measured.shift_m - departure, [_from_theta(best.x)])
    values = _from_theta(best.x)
    dof = max(1, best.fun.size - best.x.size)
    chi2 = 2 * best.cost / dof
    jac = _jacobian(residual, best.x, lo, hi)
    blind = np.linalg.norm(jac, axis=0) < 1e-9 * max(np.linalg.norm(jac), 1e-300)
    cov = np.linalg.pinv(jac.T @ jac) * max(1.0, chi2)
    sd_theta = np.sqrt(np.clip(np.diag(cov), 0, None))
    sd_theta[blind] = np.inf  # the profile does not move with it: not constrained
    # back to field units: d(exp θ) = exp θ dθ for the log-scaled ones
    uncertainties = {k: (float(values[k] * s if FITTED[k][4] else s) if np.isfinite(s) else None)
                     for k, s in zip(FITTED, sd_theta)}
    scale = np.where((sd_theta > 0) & np.isfinite(sd_theta), sd_theta, 1.0)
    correlation = cov / np.outer(scale, scale)
    instrument = _with(start, values)
    noise = flattest_noise((trace[train], retrace[train]))   # white height noise σ where the sample is flattest
    instrument = instrument.model_copy(update={"z_loop": instrument.z_loop.model_copy(
        update={"height_noise_nm": float(min(noise * 1e9, 100.0))})})
    facts = {"height_noise_m": noise, "chi2_per_dof": chi2, "full_scan_minus_fast_model_m": departure,
             # a direction-dependent Z offset (feedback error, tilt levelled per direction); the twin
             # does not model it and NSL2 (binarized at each image's mean) does not see it
             "retrace_minus_trace_height_m": float(np.median(retrace - trace))}
    shift_x, shift_y = image_shift(trace, retrace, (dx, scan.size_m[1] / scan.lines))
    facts["whole_image_shift_m"] = {"x": shift_x, "y": shift_y}
    if pitch_m is not None:
        facts["absolute"] = _absolute(trace, retrace, dx, pitch_m)
    train_rms = float(np.sqrt(np.mean((best.fun / weight) ** 2)))
    return ImageCalibration(instrument, values, uncertainties, correlation, measured, train_rms, facts)


def _absolute(trace, retrace, dx: float, pitch_m: float) -> dict:
    """The absolute scale of each scan direction against a known pitch, and how it varies across the field.

    ``period_over_pitch`` is the whole image's period along x over the pitch (1 for a lattice axis
    along x and a true scale; a rotated lattice shows its own projection); ``local_over_mean`` the
    period per window (4) over the image's: > 1 where that direction stretches the image (the
    stage moved less than intended), < 1 where it compresses it.
    """
    out = {"pitch_m": pitch_m}
    for label, image in (("trace", trace), ("retrace", retrace)):
        whole, local = local_period_m(image, dx, pitch_m)
        out[label] = {"period_m": whole, "period_over_pitch": whole / pitch_m, "local_period_m": local,
                      "local_over_mean": local / whole}
    return out
