"""The Z loop's error signal beside the height: picked from instrument files, carried by the image
record, and read against the held-out gap of an image diagnosis (``where.z_loop``)."""

from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from afmsim.diagnosis.images.attribute import diagnose_image_record
from afmsim.diagnosis.images.localise import REGULATION_SIGMA, out_of_regulation
from afmsim.diagnosis.images.record import load_images, within_budget
from afmsim.readers import pick_error_pair, read_afm_file

from vendor_files import write_ibw, write_nanoscope

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real-data" / "afm"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason="../shared/real-data/afm not present")


def test_an_error_channel_is_preferred_to_an_amplitude_and_that_to_a_deflection(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.normal(0.0, 1e-9, (16, 20))
    layers = {"HeightTrace": img, "HeightRetrace": img, "DeflectionTrace": img, "DeflectionRetrace": img,
              "AmplitudeTrace": img, "AmplitudeRetrace": img, "PhaseTrace": img, "PhaseRetrace": img}
    note = {"FastScanSize": 2e-6, "SlowScanSize": 1.6e-6, "ScanRate": 1.0}
    afm = read_afm_file(write_ibw(tmp_path / "ac.ibw", layers, note))
    trace, retrace = pick_error_pair(afm, (16, 20))
    assert (trace.name, trace.direction, retrace.direction) == ("Amplitude", "trace", "retrace")
    assert pick_error_pair(afm, (8, 20)) is None  # not on the height's grid
    contact = {k: v for k, v in layers.items() if not k.startswith("Amplitude")}
    assert pick_error_pair(read_afm_file(write_ibw(tmp_path / "c.ibw", contact, note)), (16, 20))[0].name == "Deflection"
    one_way = {k: v for k, v in contact.items() if k != "DeflectionRetrace"}  # and phase is no error signal
    assert pick_error_pair(read_afm_file(write_ibw(tmp_path / "p.ibw", one_way, note)), (16, 20)) is None

    raw = rng.integers(-20000, 20000, (16, 20)).astype(np.int16)
    path = write_nanoscope(tmp_path / "tapping.001", [(n, d, raw) for n in ("Height", "Amplitude", "Amplitude Error")
                                                      for d in ("Trace", "Retrace")])
    assert pick_error_pair(read_afm_file(path), (16, 20))[0].name == "Amplitude Error"


def _grating_pair(lag_retrace_s: float, shift_retrace_m: float = 0.0, seed: int = 0):
    """A 100 nm grating (period 8 µm, 20 µm scan) in contact at 1 line/s, 64 lines × 128 pixels. The
    trace's Z loop follows within 20 µs; the retrace's is a first-order lag of ``lag_retrace_s``
    (scipy's ``lfilter``, not afmsim's Z loop), and its stage lags ``shift_retrace_m`` behind. The
    error signal is the deflection, surface − recorded height, with 0.1 nm noise on every image."""
    rng = np.random.default_rng(seed)
    pixels, sub, lines = 128, 16, 64
    x = (np.arange(pixels * sub) + 0.5) / (pixels * sub) * 20e-6
    dt = 0.5 / x.size  # half a line per direction

    def scan(shift, tau, backward):
        s = 100e-9 * (np.sin(2 * np.pi * (x - shift) / 8e-6 + 0.3) > 0)
        s = s[::-1] if backward else s  # the retrace runs right → left
        a = np.exp(-dt / tau)
        h = lfilter([1 - a], [1, -a], s, zi=[a * s[0]])[0]
        h, e = h.reshape(pixels, sub).mean(axis=1), (s - h).reshape(pixels, sub).mean(axis=1)
        return (h[::-1], e[::-1]) if backward else (h, e)

    (h_t, e_t), (h_r, e_r) = scan(0.0, 20e-6, False), scan(shift_retrace_m, lag_retrace_s, True)
    noisy = lambda line: np.tile(line, (lines, 1)) + rng.normal(0.0, 0.1e-9, (lines, pixels))  # noqa: E731
    return {"trace": noisy(h_t), "retrace": noisy(h_r), "error_trace": noisy(e_t), "error_retrace": noisy(e_r),
            "error_channel": "Deflection (m)", "scan_size_m": [20e-6, 20e-6], "line_rate_hz": 1.0}


def test_the_gap_is_located_on_the_pixels_where_the_retraces_own_error_signal_is_off_its_setpoint():
    """A retrace whose Z loop lags by 2 ms: its deflection leaves the setpoint after every edge, and the
    gap is there. A retrace mislaid by its stage (0.3 µm) with a loop that follows leaves a gap at the
    same edges while its deflection holds the setpoint: none of the gap is located there."""
    rec = load_images(_grating_pair(2e-3))
    assert rec.error_channel == "Deflection (m)" and rec.error_retrace.shape == rec.retrace.shape
    rep, summary, _ = diagnose_image_record(rec, candidates=[])
    z = rep["unexplained"]["where"]["z_loop"]
    assert rep["status"] == "unexplained" and z["directions"] == "retrace" and z["threshold_sigma"] == REGULATION_SIGMA
    assert z["share"] >= 0.9 and z["sample_fraction"] <= 0.2, z
    assert "error signal off its setpoint (retrace's own Deflection (m) > 5σ)" in summary
    assert rep["images"]["error_channel"] == "Deflection (m)"

    rep, summary, _ = diagnose_image_record(load_images(_grating_pair(20e-6, 0.3e-6)), candidates=[])
    z = rep["unexplained"]["where"]["z_loop"]
    assert rep["status"] == "unexplained" and rep["where"]["features"]["edges"]["share"] > 0.5
    assert z["share"] < 0.1, z


def test_out_of_regulation_is_measured_from_the_signals_own_median_and_scatter():
    rng = np.random.default_rng(4)
    error = 0.35 + rng.normal(0.0, 1e-3, (20, 50))  # an amplitude held at 0.35 V
    error[5, 10:14] = 0.42  # the free amplitude: the tip off the surface
    error[7, 3] = np.nan
    mask = out_of_regulation(error)
    assert mask.sum() == 4 and mask[5, 10:14].all() and not mask[7, 3]
    error[5, 20] = 0.35 + 0.8 * REGULATION_SIGMA * 1e-3  # inside the threshold
    assert out_of_regulation(error).sum() == 4
    assert out_of_regulation(np.full((4, 4), 0.35)) is None  # a constant signal gives no reading


def test_error_images_must_come_in_pairs_on_the_heights_grid():
    pair = _grating_pair(20e-6)
    with pytest.raises(ValueError, match="error_retrace given without error_trace"):
        load_images({k: v for k, v in pair.items() if k != "error_trace"})
    with pytest.raises(ValueError, match=r"error_trace must have the heights' shape \(64, 128\)"):
        load_images({**pair, "error_trace": pair["error_trace"][:, :100]})
    wide = {**pair, **{k: np.repeat(pair[k], 5, axis=1) for k in ("trace", "retrace", "error_trace", "error_retrace")}}
    cut, done = within_budget(load_images(wide))  # 640 pixels: averaged in pairs, the error signal alike
    assert done["pixels_per_bin"] == 2 and cut.error_trace.shape == cut.trace.shape == (64, 320)


@needs_real
def test_on_the_real_circles_scan_most_of_the_gap_lies_where_the_amplitude_is_off_its_setpoint():
    """``circles.nid`` (dynamic mode, 50 µm): nine tenths of the gap lie on the seventh of the pixels
    where the retrace's amplitude is off its setpoint (the pattern's edges)."""
    rec = load_images(REAL / "circles.nid")
    assert rec.error_channel == "Amplitude (V)"
    rep, summary, _ = diagnose_image_record(rec, candidates=[])
    z = rep["unexplained"]["where"]["z_loop"]
    assert z["share"] > 0.8 and z["sample_fraction"] < 0.2, z
    assert "retrace's own Amplitude (V) > 5σ" in summary
