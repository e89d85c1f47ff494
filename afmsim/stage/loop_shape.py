"""Set a plant's asymmetry (``skew``) from a measured loop's shape instead of from paper Table 2.

The default plants take ``skew`` from the paper's Table 2 (a calibration:
docs/reference-results.md). :func:`skew_from_loop` sets it from other evidence — the shape of a measured steady
loop, both axes normalised to [0, 1], so only the shape counts (its width and asymmetry), not the
stage's travel or voltage range. The measured cycle's drive is mapped onto 0 → ``calibration
amplitude`` (9.1 V), the plant is run from rest through three cycles of it, and the last cycle is
compared with the measurement (RMS of the normalised displacement, same samples).

:func:`mean_cycle` folds a periodic record (e.g. ``../shared/real-data/piezo-sine-150V-1Hz.csv``)
into one cycle, averaging the sensor noise over the periods.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .hysteresis_models import HysteresisModel

__all__ = ["mean_cycle", "loop_shape_error", "skew_from_loop"]


def mean_cycle(t, v, x, period_s: float, start_s: float, n_bins: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """One cycle ``(v, x)`` averaged over the whole periods of the record after ``start_s`` (s),
    in ``n_bins`` phase bins, starting at the drive's minimum."""
    t, v, x = (np.asarray(a, dtype=np.float64) for a in (t, v, x))
    periods = int(np.floor((t[-1] - start_s) / period_s))
    if periods < 1:
        raise ValueError(f"the record holds no whole period of {period_s} s after {start_s} s")
    keep = (t >= start_s) & (t < start_s + periods * period_s)
    phase_bin = np.minimum(((t[keep] - start_s) / period_s % 1.0 * n_bins).astype(int), n_bins - 1)
    counts = np.bincount(phase_bin, minlength=n_bins)
    if np.any(counts == 0):
        raise ValueError(f"n_bins={n_bins} is finer than the record's sampling")
    v_mean = np.bincount(phase_bin, v[keep], n_bins) / counts
    x_mean = np.bincount(phase_bin, x[keep], n_bins) / counts
    first = int(np.argmin(v_mean))
    return np.roll(v_mean, -first), np.roll(x_mean, -first)


def _normalised(a: np.ndarray) -> np.ndarray:
    return (a - a.min()) / np.ptp(a)


def loop_shape_error(model: HysteresisModel, v_cycle, x_cycle) -> float:
    """RMS difference (fraction of travel) between the normalised measured cycle and the model's
    steady cycle under the same drive mapped onto 0 → ``model.calibration_amplitude_V``."""
    u = _normalised(np.asarray(v_cycle, dtype=np.float64)) * model.calibration_amplitude_V
    drive = np.r_[np.linspace(0.0, u[0], 50), np.tile(u, 3)]
    y = model.apply(drive)[-u.size:]
    return float(np.sqrt(np.mean((_normalised(y) - _normalised(np.asarray(x_cycle, dtype=np.float64))) ** 2)))


def skew_from_loop(model: HysteresisModel, v_cycle, x_cycle, skews=np.linspace(-1.0, 1.0, 41)) -> tuple[float, dict]:
    """The ``skew`` of ``model``'s family (other parameters kept) whose steady loop matches the
    measured cycle's shape best; returns ``(skew, {skew: shape error})``."""
    errors = {round(float(s), 6): loop_shape_error(replace(model, skew=round(float(s), 6)), v_cycle, x_cycle)
              for s in skews}
    return min(errors, key=errors.get), errors
