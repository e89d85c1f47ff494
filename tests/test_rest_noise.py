"""The sensor's noise at rest (``afmsim.diagnosis.loops.rest``): measured on a record's initial rest,
white or coloured, compared band by band with the held-out remainder, and reported by the diagnosis."""

import numpy as np
import pytest
from scipy.signal import butter, sosfiltfilt

from afmsim.diagnosis import diagnose_loops
from afmsim.diagnosis.loops.record import load_record
from afmsim.diagnosis.loops.rest import COLOURED_RATIO, MIN_REST_SAMPLES, against_rest, rest_noise
from afmsim.stage import AsymmetricPreisach

FS, REST_S = 500.0, 2.0


def _record(rng, *, coloured_rms=0.0, white=2e-9, rest_s=REST_S, duration_s=12.0):
    """A 1 Hz, 0–10 V sine after ``rest_s`` at 0 V on afmsim's stage; white noise plus, optionally,
    noise band-limited to 5–30 Hz (vibration) of RMS ``coloured_rms`` (m)."""
    t = np.arange(int(duration_s * FS)) / FS
    v = np.where(t < rest_s, 0.0, 5.0 - 5.0 * np.cos(2 * np.pi * (t - rest_s)))
    x = AsymmetricPreisach().apply(v) + white * rng.standard_normal(t.size)
    if coloured_rms:
        band = sosfiltfilt(butter(4, [5.0, 30.0], btype="band", fs=FS, output="sos"), rng.standard_normal(t.size))
        x = x + coloured_rms * band / band.std()
    return t, v, x


def test_rest_noise_is_the_sensor_reading_before_the_drive_moves():
    rng = np.random.default_rng(11)
    white = rest_noise(load_record(_record(rng)), 2e-9)
    assert white is not None and 0 <= white.deviation.size - int(REST_S * FS) <= 3  # the cosine start leaves 0 V slowly
    assert 0.85 < white.to_white < COLOURED_RATIO and not white.coloured
    t, v, x = _record(rng, coloured_rms=6e-9)
    x = x + 1e-9 * t  # a drift during the rest is a trend, not noise
    coloured = rest_noise(load_record((t, v, x)), 2e-9)
    assert coloured.coloured and coloured.rms == pytest.approx(np.hypot(2e-9, 6e-9), rel=0.15)
    assert rest_noise(load_record(_record(rng, rest_s=0.0)), 2e-9) is None  # moving from the first sample
    short = (MIN_REST_SAMPLES - 10) / FS
    assert rest_noise(load_record(_record(rng, rest_s=short)), 2e-9) is None
    t, v, x = _record(rng, white=0.0)  # a sensor that reads nothing at rest sets no noise there
    assert rest_noise(load_record((t, v, np.round(x, 8))), 2e-9) is None


def test_against_rest_separates_the_sensor_noise_from_a_drive_locked_remainder():
    rng = np.random.default_rng(12)
    t, v, x = _record(rng, coloured_rms=6e-9)
    rest = rest_noise(load_record((t, v, x)), 2e-9)
    moving = t >= REST_S
    _, _, noise_again = _record(np.random.default_rng(13), coloured_rms=6e-9)  # the same sensor, another stretch
    noise = noise_again[moving] - AsymmetricPreisach().apply(v)[moving]
    alike = against_rest(rest, v, noise)
    assert alike["gap_to_rest_noise"] == pytest.approx(1.0, abs=0.2)
    for name in ("excitation_band", "high"):  # where the sensor's noise has its power, the two read alike
        band = alike["bands"][name]
        assert 0.6 < band["remainder_rms"] / band["rest_rms"] < 1.6
    locked = noise + 8e-9 * np.sin(2 * np.pi * 2.0 * (t[moving] - REST_S))  # the drive's second harmonic
    found = against_rest(rest, v, locked)
    band = found["bands"]["excitation_band"]
    assert found["bands_hz"]["excitation_band"][0] < 2.0 < found["bands_hz"]["excitation_band"][1]
    assert band["excess_rms"] == pytest.approx(8e-9 / np.sqrt(2), rel=0.3)
    assert band["excess_rms"] > max(band["rest_rms"], found["bands"]["high"]["excess_rms"])


def test_the_diagnosis_reports_the_noise_at_rest_beside_the_white_floor():
    t, v, x = _record(np.random.default_rng(14), coloured_rms=6e-9)
    rep, summary = diagnose_loops((t, v, x))
    rest = rep["baseline"]["rest_noise"]
    assert rest["coloured"] and 0 <= rest["samples"] - int(REST_S * FS) <= 3
    assert rest["duration_s"] == pytest.approx(REST_S, abs=0.01)
    assert rest["to_white_noise"] == pytest.approx(rest["rms"] / rep["baseline"]["noise_floor"], rel=1e-3)
    # the status keeps the white floor; the rest says how much of the gap the sensor's own noise is
    assert rep["baseline"]["gap_to_noise"] == pytest.approx(rep["baseline"]["rms_gap"] / rep["baseline"]["noise_floor"],
                                                            rel=1e-3)
    assert rest["against"]["gap_to_rest_noise"] < 1.5 < rep["baseline"]["gap_to_noise"]
    assert "Noise at rest: the sensor reads" in summary and "coloured noise" in summary
    t, v, x = _record(np.random.default_rng(15), rest_s=0.0)
    assert diagnose_loops((t, v, x))[0]["baseline"]["rest_noise"] is None
