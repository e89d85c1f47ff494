"""The fast scan-loop kernels against their direct (slow, readable) formulations.

Each compiled kernel of the scan loop was rearranged for speed; these tests pin that the
rearrangement is the same mathematics: equal results up to rounding.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.ndimage import map_coordinates
from scipy.signal import lfilter, sosfilt

from afmsim.hysteresis import DIAPI, osp
from afmsim.hysteresis.operators import osp_weighted
from afmsim.hysteresis.fitting import branch_signs
from afmsim.samples import HeightMap
from afmsim.scan import RasterGeometry, ZFeedback, ZStage, raster_trajectory, surface_under_tip, track_surface
from afmsim.stage import AsymmetricPreisach, AxisParams, PiezoAxis
from afmsim.stage.axis import creep_sos, resonance_sos
from afmsim.stage.hysteresis_models import _preisach_kernel

UM, NM = 1e-6, 1e-9


# ----------------------------------------------------------------------------------------------
# feedforward: weighted OSP sums
# ----------------------------------------------------------------------------------------------
steps = arrays(np.float64, st.integers(1, 80), elements=st.sampled_from([-2.0, -0.5, 0.0, 0.0, 0.7, 1.5]))


@settings(max_examples=100, deadline=None)
@given(steps, st.floats(-3, 3), st.integers(0, 2**32 - 1))
def test_osp_weighted_is_the_branch_weighted_operator_sum(increments, h0, seed):
    d = np.cumsum(increments)                      # zero increments included: they keep the branch
    rng = np.random.default_rng(seed)
    widths = np.sort(rng.uniform(0, 3, 5))
    weights = rng.normal(size=(2, 5))
    H = osp(d, widths, h0)
    expected = np.where(branch_signs(d) > 0, H @ weights[0], H @ weights[1])
    np.testing.assert_allclose(osp_weighted(d, widths, weights, h0), expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(osp_weighted(d, widths, weights[0], h0), H @ weights[0], rtol=1e-12, atol=1e-12)


def test_osp_weighted_rejects_weights_of_the_wrong_shape():
    with pytest.raises(ValueError, match="weights must have shape"):
        osp_weighted(np.arange(5.0), np.arange(3.0), np.ones((3, 3)))


def test_diapi_prediction_equals_eq3_with_the_stored_operator_outputs():
    t = np.linspace(0, 2, 801)
    d = 30 * UM * np.abs(np.sin(np.pi * t)) ** 1.3
    v = d / (11 * UM) + 0.4 * np.sin(2 * np.pi * t) ** 2
    model = DIAPI.fit(d, v, n_operators=8)
    probe = 25 * UM * (0.5 - 0.5 * np.cos(3 * np.pi * t))
    H = osp(probe - model.offset, model.widths, model.h0)
    direct = np.where(branch_signs(probe) > 0, H @ model.weights_trace, H @ model.weights_retrace) + model.bias
    np.testing.assert_allclose(model.predict(probe), direct, rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------------------------
# surface lookup
# ----------------------------------------------------------------------------------------------
def test_surface_lookup_equals_scipy_bilinear_with_nearest_edges():
    rng = np.random.default_rng(4)
    surface = HeightMap(rng.normal(0, 100 * NM, (23, 31)), (0.2 * UM, 0.3 * UM), origin=(1 * UM, -2 * UM))
    x = rng.uniform(0, 9 * UM, (40, 25))           # beyond both edges of the 6.2 µm-wide map too
    y = rng.uniform(-4 * UM, 6 * UM, (40, 25))
    rows = (y - surface.origin[1]) / surface.pixel_size[1]
    cols = (x - surface.origin[0]) / surface.pixel_size[0]
    expected = map_coordinates(surface.z, [rows, cols], order=1, mode="nearest")
    got = surface_under_tip(surface, x, y)
    assert got.shape == x.shape
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * np.ptp(surface.z))
    assert np.isnan(surface_under_tip(surface, np.nan, 0.0))       # no index is read for a NaN position


# ----------------------------------------------------------------------------------------------
# Z loop
# ----------------------------------------------------------------------------------------------
def direct_z_loop(surface, sample_rate_hz, stage: ZStage, feedback: ZFeedback, noise):
    """The Z loop exactly as the module docstring writes it, one loop step at a time (slow): the
    recorded heights and each sample's mean error e = δ + noise − setpoint."""
    n = surface.size
    substeps = max(1, int(np.ceil(feedback.loop_rate_hz / sample_rate_hz)))
    dt = 1.0 / (sample_rate_hz * substeps)
    s_nom = stage.sensitivity_m_per_V
    s_true = s_nom / (1.0 - stage.bw_alpha) if stage.hysteresis else s_nom
    u_max = stage.max_voltage_V
    u = u_centre = 0.5 * u_max
    h = integral = 0.0
    b0 = surface[0] - feedback.setpoint_m - s_true * u_centre
    out, err = np.empty(n), np.empty(n)
    for k in range(n):
        prev, nxt = surface[max(k - 1, 0)], surface[min(k + 1, n - 1)]
        acc = acc_e = 0.0
        for j in range(substeps):
            frac = (j + 0.5) / substeps - 0.5
            s = surface[k] + frac * ((surface[k] - prev) if frac < 0 else (nxt - surface[k]))
            delta = max(s - (b0 + s_true * (u - h)), 0.0)
            e = delta + noise[k] - feedback.setpoint_m
            acc_e += e
            integral += e * dt
            u_new = min(max(u_centre + (feedback.kp * e + feedback.ki_per_s * integral) / s_nom, 0.0), u_max)
            if stage.hysteresis:
                du = u_new - u
                h += stage.bw_alpha * du - stage.bw_beta_per_V * abs(du) * h - stage.bw_gamma_per_V * du * abs(h)
            u = u_new
            acc += u
        out[k] = acc / substeps * s_nom
        err[k] = acc_e / substeps
    return out - out[0] + surface[0], err


@pytest.mark.parametrize("hysteresis", [True, False])
@pytest.mark.parametrize("case", ["steps_and_parachuting", "saturating"])
def test_z_loop_kernel_equals_the_direct_loop(hysteresis, case):
    fs = 5000.0                                                    # 10 loop steps per sample
    k = np.arange(400)
    if case == "steps_and_parachuting":                            # up and down steps, a slope, noise
        surface = 300 * NM * ((k > 80) & (k < 200)) + 2 * NM * np.maximum(k - 250, 0)
        stage, feedback = ZStage(hysteresis=hysteresis), ZFeedback()
    else:                                                          # 2 µm steps on a 1 µm-travel stage
        surface = np.where(k < 100, 0.0, 2 * UM) - np.where(k < 300, 0.0, 4 * UM)
        stage = ZStage(hysteresis=hysteresis, max_voltage_V=1 * UM / 0.6e-6)
        feedback = ZFeedback(ki_per_s=20000.0, kp=0.5)
    noise = np.random.default_rng(8).normal(0.0, feedback.deflection_noise_m, surface.size)
    expected, expected_error = direct_z_loop(surface, fs, stage, feedback, noise)
    error = np.empty(surface.size)
    got = track_surface(surface, fs, stage, feedback, np.random.default_rng(8), error=error)
    if case == "saturating":                                       # the drive sits on its upper clip
        assert np.count_nonzero(np.isclose(got, got.max(), rtol=0, atol=1e-6 * NM)) > 100
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9 * np.ptp(expected))
    np.testing.assert_allclose(error, expected_error, rtol=0, atol=1e-9 * np.ptp(expected))
    np.testing.assert_array_equal(track_surface(surface, fs, stage, feedback, np.random.default_rng(8)), got)


def test_the_error_signal_holds_its_setpoint_and_sits_at_minus_the_setpoint_while_the_tip_parachutes():
    """A 300 nm step down at ki = 3000 /s, setpoint 20 nm: off the surface the deflection is 0, so the
    error is −setpoint (± the 0.1 nm noise) until the base has fallen the step less the deflection it
    held, 280 nm at ki·setpoint (4.7 ms); on the flats the error averages 0; the step up drives it
    positive."""
    fs, feedback = 10_000.0, ZFeedback()
    k = np.arange(600)
    surface = 300 * NM * ((k >= 100) & (k < 400))
    error = np.empty(surface.size)
    track_surface(surface, fs, ZStage(hysteresis=False), feedback, np.random.default_rng(2), error=error)
    fall_samples = int((300 * NM - feedback.setpoint_m) / (feedback.ki_per_s * feedback.setpoint_m) * fs)  # 46
    off = error[401:400 + fall_samples - 2]
    np.testing.assert_allclose(off, -feedback.setpoint_m, atol=5 * feedback.deflection_noise_m)
    assert error[400 + fall_samples + 20:].mean() == pytest.approx(0.0, abs=0.05 * NM)
    assert abs(error[300:399].mean()) < 0.05 * NM and error[100:103].max() > 50 * NM  # 399 spans the step
    with pytest.raises(ValueError, match="error must be a contiguous float64 array of shape"):
        track_surface(surface, fs, ZStage(), feedback, np.random.default_rng(2), error=np.empty(10))


# ----------------------------------------------------------------------------------------------
# plant and imaging
# ----------------------------------------------------------------------------------------------
def test_preisach_kernel_continues_from_a_stored_state():
    model = AsymmetricPreisach(n_levels=16)
    u = np.clip(np.cumsum(np.random.default_rng(5).normal(0, 0.3, 3000)) % 12.0, 0, 10.0)
    n, delta = model.n_levels, model.u_max_V / model.n_levels
    whole = np.empty_like(u)
    _preisach_kernel(u, delta, model.density, np.zeros((n, n)), 0.0, whole)
    parts, state = np.empty_like(u), np.zeros((n, n))
    last = _preisach_kernel(u[:1234], delta, model.density, state, 0.0, parts[:1234])
    _preisach_kernel(u[1234:], delta, model.density, state, last, parts[1234:])
    np.testing.assert_allclose(parts, whole, rtol=0, atol=1e-13)


def test_one_sosfilt_pass_equals_creep_then_resonance():
    axis = PiezoAxis(AxisParams(saturation_enabled=False, amplifier_enabled=False, drift_enabled=False))
    dt = 1 / 4096
    t = np.arange(20000) * dt
    v = 3.0 * (1 - np.abs(1 - 2 * ((t * 2.0) % 1.0)))
    static = axis.static_displacement(v)
    creep = sosfilt(creep_sos(axis.params.creep_gamma, dt), static)
    b, a = resonance_sos(axis.params.resonance_hz, axis.params.damping_ratio, dt)[0].reshape(2, 3)
    np.testing.assert_allclose(axis.mechanics(t, v), lfilter(b, a, creep), rtol=0, atol=1e-12 * np.ptp(creep))
    np.testing.assert_allclose(axis.dynamics(t, creep), lfilter(b, a, creep), rtol=0, atol=1e-12 * np.ptp(creep))


@pytest.mark.parametrize("samples_per_pixel", [3, 13])
def test_images_are_the_mean_over_each_pixels_samples(samples_per_pixel):
    geometry = RasterGeometry(size=(6 * UM, 3 * UM), offset=(1 * UM, 1 * UM), pixels=7, lines=3,
                              samples_per_pixel=samples_per_pixel, approach_s=0.05)
    trajectory = raster_trajectory(geometry)
    values = np.random.default_rng(2).normal(size=trajectory.t.size)
    trace, retrace = trajectory.to_images(values)
    frame = values[trajectory.frame_start:].reshape(3, 2, 7, samples_per_pixel).mean(axis=3)
    np.testing.assert_allclose(trace, frame[:, 0], rtol=1e-14)
    np.testing.assert_allclose(retrace, frame[:, 1, ::-1], rtol=1e-14)
