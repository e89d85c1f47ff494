"""Tests of the simulated XY piezo stage (afmsim.stage): every injected effect, and the paper calibration."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import csd, sosfilt, welch

from afmsim.stage import (AsymmetricDuhem, AsymmetricPreisach, AxisParams, PiezoAxis, XYStage, creep_bank,
                          default_stage, identification_experiment, triangle_wave)
from afmsim.stage.axis import creep_sos
from afmsim.stage.hysteresis_models import _preisach_kernel

ALL_OFF = dict(saturation=False, amplifier=False, hysteresis=False, creep=False, drift=False, resonance=False,
               noise=False)


def only(stage: XYStage, *effects: str, coupling: bool = False) -> XYStage:
    """The stage with every effect off except ``effects``."""
    flags = dict(ALL_OFF)
    for e in effects:
        flags[e] = True
    return stage.with_effects(coupling=coupling, **flags)


def loop_width(stage: XYStage, amplitude: float, n: int = 2000) -> tuple[float, float]:
    """(max vertical gap between the branches of a 0→A→0 loop (m), its fraction of the travel)."""
    t, v = triangle_wave(amplitude, 1.0, n, cycles=1)
    x, _ = stage.move(t, v, np.zeros_like(v))
    half = n // 2
    up, down = x[: half + 1], x[half:][::-1]
    gap = np.max(np.abs(down - up))
    return gap, gap / np.ptp(x)


def rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


# ----------------------------------------------------------------------------------------------
# calibration against the paper (acceptance test)
# ----------------------------------------------------------------------------------------------
def table2(stage: XYStage, cycle: int, n_experiments: int = 10):
    from afmsim.hysteresis import DIAPI, SPI

    errors = []
    for seed in range(n_experiments):
        rec = identification_experiment(stage, np.random.default_rng(1000 + seed), amplitude_V=9.1,
                                        frequency_hz=1.0, sample_rate_hz=1000.0, cycles=2)
        d, v = rec.cycle(cycle)
        spi, diapi = SPI.fit(d, v, n_operators=10), DIAPI.fit(d, v, n_operators=10)
        errors.append((rms(spi.predict(d) - v), rms(diapi.predict(d) - v)))
    return np.array(errors)


def test_paper_table2_calibration():
    """Paper Table 2: SPI 0.080 V, DIAPI 0.021 V mean RMS (ratio 0.26). Fit and evaluate on one cycle of
    each of 10 experiments with fresh sensor-noise seeds, default stage with all physics on.

    Cycle 1 (the second cycle: the stage in its periodic regime, as a running 1 Hz drive records it)
    is the calibrated one; cycle 0 (first rise from the de-energised state) must at least keep DIAPI < SPI.
    """
    stage = default_stage()
    err = table2(stage, cycle=1)
    spi, diapi = err[:, 0], err[:, 1]
    ratio = diapi.mean() / spi.mean()
    assert 0.15 <= ratio <= 0.45, (spi.mean(), diapi.mean(), ratio)
    assert np.all(diapi < spi)
    assert 0.05 <= spi.mean() <= 0.15, spi.mean()
    assert 0.005 <= diapi.mean() <= 0.05, diapi.mean()
    err0 = table2(stage, cycle=0, n_experiments=3)
    assert np.all(err0[:, 1] < err0[:, 0])


def test_paper_travel_and_sensitivity():
    rec = identification_experiment(default_stage(), np.random.default_rng(0))
    travel = np.ptp(rec.true_displacement)
    assert 98e-6 <= travel <= 103e-6  # ~100 µm at 9.1 V (paper §3.2)
    assert 10e-6 <= travel / 9.1 <= 11.3e-6


def test_symmetric_plant_is_fitted_by_spi():
    """Control for the calibration test: without the density skew the plant's loop is (nearly)
    centrally symmetric and the SPI-vs-DIAPI advantage collapses."""
    from afmsim.hysteresis import DIAPI, SPI

    stage = only(default_stage(AsymmetricPreisach(skew=0.0)), "hysteresis")
    t, v = triangle_wave(9.1, 1.0, 1000.0, cycles=1)
    d, _ = stage.move(t, v, np.zeros_like(v))
    e_spi = rms(SPI.fit(d, v).predict(d) - v)
    e_diapi = rms(DIAPI.fit(d, v).predict(d) - v)
    assert e_diapi / e_spi > 0.5


# ----------------------------------------------------------------------------------------------
# hysteresis
# ----------------------------------------------------------------------------------------------
def test_full_range_loop_width_10_to_15_percent():
    _, frac = loop_width(only(default_stage(), "hysteresis"), 9.1)
    assert 0.10 <= frac <= 0.15, frac


def test_loops_grow_with_amplitude():
    stage = only(default_stage(), "hysteresis")
    widths = [loop_width(stage, a) for a in (1.0, 3.0, 6.0, 9.1)]
    gaps, fracs = np.array(widths).T
    assert np.all(np.diff(gaps) > 0) and np.all(np.diff(fracs) > 0)
    assert 0.005 <= fracs[0] <= 0.03  # ~2 % for small signals (datasheet)


def test_loops_are_asymmetric_beyond_central_symmetry():
    """Rotate the falling branch by 180° about the loop centre: a PI (Masing) loop maps onto its rising
    branch; the default plant's does not."""
    stage = only(default_stage(), "hysteresis")
    n = 2000
    t, v = triangle_wave(9.1, 1.0, n, cycles=1)
    x, _ = stage.move(t, v, np.zeros_like(v))
    up, down = x[: n // 2 + 1], x[n // 2:][::-1]
    rotated = (x.max() + x.min()) - down[::-1]
    assert np.max(np.abs(rotated - up)) / np.ptp(x) > 0.01
    sym = only(default_stage(AsymmetricPreisach(skew=0.0)), "hysteresis")
    xs, _ = sym.move(t, v, np.zeros_like(v))
    ups, downs = xs[: n // 2 + 1], xs[n // 2:][::-1]
    assert np.max(np.abs((xs.max() + xs.min()) - downs[::-1] - ups)) < np.max(np.abs(rotated - up)) / 3


def test_preisach_kernel_matches_reference():
    model = AsymmetricPreisach(n_levels=12)
    rng = np.random.default_rng(3)
    u = np.clip(np.cumsum(rng.normal(0, 0.4, 400)) % 12.0, 0, 10.0)
    n, delta = model.n_levels, model.u_max_V / model.n_levels
    out = np.empty_like(u)
    _preisach_kernel(u, delta, model.density, np.zeros((n, n)), 0.0, out)
    levels = (np.arange(n) + 0.5) * delta
    state = np.zeros((n, n))
    ref = np.empty_like(u)
    for k, uk in enumerate(u):  # the relay rule applied to every relay, no shortcuts
        lo = np.clip((uk - levels[:, None]) / delta + 0.5, 0, 1)
        hi = np.clip((uk - levels[None, :]) / delta + 0.5, 0, 1)
        state = np.tril(np.clip(state, lo, hi))
        ref[k] = np.sum(model.density * state)
    np.testing.assert_allclose(out, ref, atol=1e-12)


def test_preisach_wipes_out_minor_loops():
    """Rate-independent Preisach memory: after a minor loop the major branch is rejoined exactly."""
    model = AsymmetricPreisach()
    up = np.linspace(0, 9.1, 911)
    minor = np.r_[np.linspace(0, 6, 601), np.linspace(6, 4, 201)[1:], np.linspace(4, 9.1, 511)[1:]]
    assert abs(model.apply(up)[-1] - model.apply(minor)[-1]) < 1e-12 * model.apply(up)[-1] + 1e-18
    # rate independence: resampling the same path changes nothing
    np.testing.assert_allclose(model.apply(np.linspace(0, 9.1, 91))[-1], model.apply(up)[-1], rtol=1e-12)


@pytest.mark.parametrize("family", ["preisach", "duhem"])
def test_both_plant_families_meet_the_datasheet_loop(family):
    """Both minor-loop laws are calibrated to the same datasheet major loop: 100 µm at 9.1 V, loop
    width 10–15 % of travel at full range, ~2 % for small signals, growing with amplitude."""
    stage = only(default_stage(family), "hysteresis")
    assert type(stage.x.params.hysteresis) is {"preisach": AsymmetricPreisach, "duhem": AsymmetricDuhem}[family]
    gaps, fracs = np.array([loop_width(stage, a) for a in (1.0, 3.0, 6.0, 9.1)]).T
    assert 0.10 <= fracs[-1] <= 0.15, fracs
    assert 0.005 <= fracs[0] <= 0.03, fracs
    assert np.all(np.diff(gaps) > 0)
    rec = identification_experiment(default_stage(family), np.random.default_rng(0))
    assert 98e-6 <= rec.true_displacement.max() <= 104e-6


def test_hysteresis_free_variant_is_linear():
    stage = default_stage()
    t, v = triangle_wave(9.1, 1.0, 1000.0, cycles=2)
    quasi_static = dict(creep=False, drift=False, resonance=False, amplifier=False)
    x_ideal, _ = stage.hysteresis_free().with_effects(**quasi_static).move(t, v, np.zeros_like(v))
    sens = stage.x.params.sensitivity_m_per_V
    np.testing.assert_allclose(x_ideal, sens * v, rtol=0, atol=1e-15)  # Y at 0 V: no coupling term
    x_real, _ = stage.with_effects(**quasi_static).move(t, v, np.zeros_like(v))
    assert np.max(np.abs(x_real - sens * v)) > 3e-6
    # everything else kept: the hysteresis-free stage still creeps
    assert stage.hysteresis_free().x.params.creep_enabled


# ----------------------------------------------------------------------------------------------
# drive chain, creep, dynamics, coupling, drift, sensor
# ----------------------------------------------------------------------------------------------
def test_saturation_clips_drive():
    stage = only(default_stage(), "saturation", "hysteresis")
    t = np.arange(100) / 1000.0
    hi, _ = stage.move(t, np.full(100, 15.0), np.zeros(100))
    top, _ = stage.move(t, np.full(100, 10.0), np.zeros(100))
    np.testing.assert_array_equal(hi, top)
    lo, _ = stage.move(t, np.full(100, -3.0), np.zeros(100))
    np.testing.assert_array_equal(lo, np.zeros(100))
    unclipped, _ = only(default_stage(), "hysteresis").move(t, np.full(100, 15.0), np.zeros(100))
    assert unclipped[-1] > top[-1] * 1.2


def test_amplifier_bandwidth_is_first_order():
    axis = PiezoAxis(AxisParams(amplifier_bandwidth_hz=3000.0))
    fs = 1e6
    t = np.arange(2000) / fs
    u = axis.drive(t, np.ones_like(t))
    tau = 1 / (2 * np.pi * 3000.0)
    k = int(round(tau * fs))
    assert abs(u[k] - (1 - np.exp(-1))) < 0.01


def test_creep_step_follows_log_law():
    gamma = default_stage().x.params.creep_gamma
    stage = only(default_stage(), "creep")
    fs = 200.0
    t = np.arange(int(100 * fs) + 1) / fs
    v = np.full_like(t, 5.0)
    x, _ = stage.move(t, v, np.zeros_like(v))
    probe = np.array([0.1, 0.3, 1, 3, 10, 30, 100])
    d = np.interp(probe, t, x)
    law = d[0] * (1 + gamma * np.log10(probe / 0.1))
    assert np.max(np.abs(d / law - 1)) < 0.15 * gamma  # within 15 % of the creep itself
    assert (d[-1] / d[0] - 1) == pytest.approx(3 * gamma, rel=0.1)  # 3 decades
    flat, _ = only(default_stage()).move(t, v, np.zeros_like(v))
    assert np.ptp(flat) == 0


def test_creep_sos_equals_parallel_bank():
    g0, c, tau = creep_bank(0.018)
    dt = 0.01
    t = np.arange(20000) * dt
    # The first-order hold reads the sampled step [0, 1, 1, ...] as a ramp over [-dt, 0]; the exact
    # continuous response to that ramp is the step response averaged over a shift u in [0, dt].
    u = (np.arange(64) + 0.5) / 64 * dt
    shifted = t[None, :, None] + u[None, None, :]
    bank = g0 + np.sum(c[:, None] * (1 - np.exp(-shifted / tau[:, None, None])).mean(axis=2), axis=0)
    step = sosfilt(creep_sos(0.018, dt), np.ones_like(t))
    assert np.max(np.abs(step[10:] - bank[10:])) < 1e-3 * 0.018 * 3  # 0.1 % of the 3-decade creep


def test_resonance_peak_in_frequency_response():
    stage = only(default_stage(), "resonance")
    f0 = stage.x.params.resonance_hz
    fs = 5000.0
    rng = np.random.default_rng(7)
    v = 5.0 + rng.normal(0, 0.5, 2**16)
    t = np.arange(v.size) / fs
    x, _ = stage.move(t, v, np.zeros_like(v))
    f, pxy = csd(v, x, fs=fs, nperseg=4096)
    _, pxx = welch(v, fs=fs, nperseg=4096)
    gain = np.abs(pxy / pxx) / stage.x.params.sensitivity_m_per_V
    peak = f[np.argmax(gain)]
    assert abs(peak - f0) < 0.05 * f0
    assert gain.max() > 10  # Q = 1/(2ζ) = 25
    assert abs(gain[np.argmin(np.abs(f - 10))] - 1) < 0.05
    no_res, _ = only(default_stage()).move(t, v, np.zeros_like(v))
    _, pxy0 = csd(v, no_res, fs=fs, nperseg=4096)
    assert np.abs(pxy0 / pxx).max() / stage.x.params.sensitivity_m_per_V < 1.05


def test_hysteresis_becomes_rate_dependent_at_high_line_rates():
    stage = default_stage().with_effects(noise=False, drift=False, creep=False)

    def loop_area(freq):
        fs = 1000.0 * freq
        t, v = triangle_wave(9.1, freq, fs, cycles=2)
        x, _ = stage.move(t, v, np.zeros_like(v))
        sl = slice(1000, 2001)  # second cycle
        return abs(np.trapezoid(x[sl], v[sl])) if hasattr(np, "trapezoid") else abs(np.trapz(x[sl], v[sl]))

    slow, fast = loop_area(1.0), loop_area(50.0)
    assert fast > 1.1 * slow  # ~17 % wider at 50 Hz lines (resonance + amplifier lag)
    assert loop_area(2.0) == pytest.approx(slow, rel=0.02)  # negligible at slow line rates


def test_cross_coupling_magnitude():
    stage = only(default_stage(), "hysteresis", coupling=True)
    t, v = triangle_wave(9.1, 1.0, 1000.0, cycles=1)
    x, y = stage.move(t, v, np.zeros_like(v))
    assert np.max(np.abs(y)) / np.max(np.abs(x)) == pytest.approx(0.005, rel=0.01)
    x2, y2 = stage.move(t, np.zeros_like(v), v)
    assert np.max(np.abs(x2)) / np.max(np.abs(y2)) == pytest.approx(0.005, rel=0.01)
    _, y_off = only(default_stage(), "hysteresis").move(t, v, np.zeros_like(v))
    assert np.all(y_off == 0)


def test_drift_rate_per_axis():
    stage = only(default_stage(), "drift")
    t = np.linspace(0, 600, 601)
    x, y = stage.move(t, np.zeros_like(t), np.zeros_like(t))
    assert np.polyfit(t, x, 1)[0] * 60 == pytest.approx(5e-9, rel=1e-6)
    assert np.polyfit(t, y, 1)[0] * 60 == pytest.approx(3e-9, rel=1e-6)


def test_sensor_noise_sigma():
    stage = default_stage()
    x = np.full(200_000, 50e-6)
    xm = stage.x.measure(x, np.random.default_rng(11))
    assert np.std(xm - x) == pytest.approx(10e-9, rel=0.02)
    assert abs(np.mean(xm - x)) < 1e-10
    np.testing.assert_array_equal(stage.with_effects(noise=False).x.measure(x, np.random.default_rng(1)), x)
    with pytest.raises(TypeError):
        stage.x.measure(x, np.random.RandomState(0))


def test_reproducible_with_same_seed():
    stage = default_stage()
    a = identification_experiment(stage, np.random.default_rng(42))
    b = identification_experiment(stage, np.random.default_rng(42))
    c = identification_experiment(stage, np.random.default_rng(43))
    np.testing.assert_array_equal(a.displacement, b.displacement)
    np.testing.assert_array_equal(a.true_displacement, c.true_displacement)
    assert not np.array_equal(a.displacement, c.displacement)


def test_triangle_wave_shape():
    t, v = triangle_wave(9.1, 1.0, 1000.0, cycles=2)
    assert t.size == 2001 and v[0] == 0 and v[500] == pytest.approx(9.1) and v[1000] == pytest.approx(0)
    assert v[1] > v[0]


def test_rejects_bad_input():
    stage = default_stage()
    with pytest.raises(ValueError):
        stage.move(np.array([0.0, 0.1, 0.3]), np.zeros(3), np.zeros(3))  # non-uniform
    with pytest.raises(ValueError):
        stage.with_effects(gravity=False)
    with pytest.raises(ValueError):
        AxisParams(v_min_V=5, v_max_V=1)
