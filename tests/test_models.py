"""Inverse hysteresis models (paper eq. 1–7 and afmsim's IIAPI / CAPI): identification, contract, errors."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from afmsim.hysteresis import CAPI, DIAPI, IIAPI, MODELS, SPI, osp, play
from afmsim.hysteresis.fitting import branch_signs, operator_widths
from afmsim.hysteresis.iiapi import invert_pi, monotone_weights

UM = 1e-6


def reversals(peaks, samples_per_segment=60, start=0.0):
    """Piecewise-linear trajectory through ``start`` and the given turning points."""
    points = np.concatenate([[start], peaks])
    return np.concatenate([np.linspace(a, b, samples_per_segment, endpoint=False) for a, b in zip(points[:-1], points[1:])]
                          + [points[-1:]])


# Several reversals at different amplitudes (nested minor loops), 0 … 100 µm: excites every operator.
D_LOOPS = reversals(np.array([100, 20, 80, 0, 60, 30, 90, 10, 100, 50, 70, 0]) * UM)


def rms(e):
    return float(np.sqrt(np.mean(np.square(e))))


# ---------------------------------------------------------------- exact recovery (eq. 6)

weight_vectors = st.lists(st.floats(-0.3, 0.3), min_size=5, max_size=5).map(np.array)


@settings(max_examples=20, deadline=None)
@given(weight_vectors, weight_vectors, st.floats(0.5, 2.0), st.floats(0.5, 2.0))
def test_diapi_recovers_known_weights(tail_trace, tail_retrace, gain_trace, gain_retrace):
    widths = operator_widths(np.ptp(D_LOOPS), 6)
    true = DIAPI(widths, np.r_[gain_trace, tail_trace] * 1e6, np.r_[gain_retrace, tail_retrace] * 1e6)
    fitted = DIAPI.fit(D_LOOPS, true.predict(D_LOOPS), n_operators=6)
    np.testing.assert_allclose(fitted.widths, widths, rtol=1e-12)
    np.testing.assert_allclose(fitted.weights_trace, true.weights_trace, rtol=1e-8, atol=1e-8 * 1e6)
    np.testing.assert_allclose(fitted.weights_retrace, true.weights_retrace, rtol=1e-8, atol=1e-8 * 1e6)
    assert fitted.offset == 0.0 and fitted.bias == 0.0


@settings(max_examples=20, deadline=None)
@given(weight_vectors, st.floats(0.5, 2.0))
def test_spi_recovers_known_weights_from_symmetric_data(tail, gain):
    widths = operator_widths(np.ptp(D_LOOPS), 6)
    true = SPI(widths, np.r_[gain, tail] * 1e6)
    fitted = SPI.fit(D_LOOPS, true.predict(D_LOOPS), n_operators=6)
    np.testing.assert_allclose(fitted.weights, true.weights, rtol=1e-8, atol=1e-8 * 1e6)


def test_diapi_on_symmetric_data_has_equal_branches():
    widths = operator_widths(np.ptp(D_LOOPS), 5)
    true = SPI(widths, np.array([1.0, -0.1, 0.05, -0.02, 0.01]) * 1e6)
    fitted = DIAPI.fit(D_LOOPS, true.predict(D_LOOPS), n_operators=5)
    np.testing.assert_allclose(fitted.weights_trace, true.weights, rtol=1e-8)
    np.testing.assert_allclose(fitted.weights_retrace, true.weights, rtol=1e-8)
    np.testing.assert_allclose(fitted.asymmetry, 0.0, atol=1e-8)


def test_bipolar_shift_fits_a_bias_and_recovers_the_loop():
    """A bipolar copy of the same loop (d − 50 µm, v − 40 V) is fitted exactly via the bias (bug fix)."""
    widths = operator_widths(np.ptp(D_LOOPS), 5)
    true = DIAPI(widths, np.array([1.0, -0.1, 0.05, -0.02, 0.01]) * 1e6, np.array([1.2, -0.2, 0.0, -0.05, 0.02]) * 1e6)
    v = true.predict(D_LOOPS)
    fitted = DIAPI.fit(D_LOOPS - 50 * UM, v - 40.0, n_operators=5)
    assert fitted.offset == pytest.approx(-50 * UM)
    np.testing.assert_allclose(fitted.weights_trace, true.weights_trace, rtol=1e-7)
    assert fitted.bias == pytest.approx(-40.0, abs=1e-6)
    np.testing.assert_allclose(fitted.predict(D_LOOPS - 50 * UM), v - 40.0, atol=1e-6)


# ---------------------------------------------------------------- widths (eq. 5 vs Table 1), branch rule, e_ω (eq. 7)

def test_width_spacings():
    np.testing.assert_allclose(operator_widths(99.9e-6, 10, "eq5"), np.arange(10) / 10 * 99.9e-6)
    table1 = operator_widths(99.9e-6, 10, "table1")
    np.testing.assert_allclose(table1 / UM, [0, 11.1, 22.2, 33.3, 44.4, 55.5, 66.6, 77.7, 88.8, 99.9], atol=1e-9)
    with pytest.raises(ValueError, match="spacing"):
        operator_widths(1.0, 10, "log")


def test_zero_increments_keep_the_branch():
    d = np.array([0.0, 1.0, 1.0, 1.0, 0.5, 0.5, 0.7, 0.7])
    np.testing.assert_array_equal(branch_signs(d), [1, 1, 1, 1, -1, -1, 1, 1])
    np.testing.assert_array_equal(branch_signs(np.array([2.0, 2.0, 1.0])), [1, 1, -1])  # leading flat: trace


def test_e_omega_is_eq7():
    widths = operator_widths(np.ptp(D_LOOPS), 3)
    model = DIAPI(widths, np.array([0.1068, -0.0080, -0.0046]), np.array([0.1274, -0.0204, -0.0094]))
    np.testing.assert_allclose(model.asymmetry, [(0.1068 - 0.1274) / 0.1274, (-0.0080 + 0.0204) / -0.0204,
                                                 (-0.0046 + 0.0094) / -0.0094])
    # Table 1's |e_ω| of rows 1–3 (16 %, 61 %, 51 %)
    np.testing.assert_allclose(np.abs(model.asymmetry), [0.16, 0.61, 0.51], atol=0.01)
    fitted = DIAPI.fit(D_LOOPS, DIAPI(widths, model.weights_trace * 1e6, model.weights_retrace * 1e6).predict(D_LOOPS), 3)
    np.testing.assert_allclose(fitted.asymmetry, model.asymmetry, rtol=1e-7)
    assert fitted.params()["e_omega"] == pytest.approx(model.asymmetry.tolist(), rel=1e-7)


# ---------------------------------------------------------------- every model: errors and contract

def bipolar_loop(n_cycles=3, samples=200, asymmetric=True):
    """A bipolar asymmetric major loop (±20 µm, ±150 V) from an independent play-operator plant."""
    t = np.arange(n_cycles * samples) / samples
    v = 150 * np.sin(2 * np.pi * t + np.pi / 2)
    y = play(v, np.array([0.0, 10, 25, 50, 80]), 0.0) @ np.array([0.55, 0.12, 0.1, 0.08, 0.05])
    d = (y + (0.002 * y**2 if asymmetric else 0.0)) * 1.3e-7
    return d - d.mean(), v


@pytest.mark.parametrize("name", sorted(MODELS))
@pytest.mark.parametrize("problem, mutate", [
    ("NaN", lambda d, v: (np.where(np.arange(d.size) == 7, np.nan, d), v)),
    ("lengths differ", lambda d, v: (d, v[:-1])),
    ("constant", lambda d, v: (np.full_like(d, 1e-6), v)),
    ("too few samples", lambda d, v: (d[:9], v[:9])),
    ("1-D", lambda d, v: (d[:, None], v)),
])
def test_bad_inputs_raise_value_error_naming_the_problem(name, problem, mutate):
    d, v = mutate(*bipolar_loop())
    with pytest.raises(ValueError, match=problem):
        MODELS[name].fit(d, v, n_operators=5)


def test_constant_voltage_is_named():
    d, v = bipolar_loop()
    for model in MODELS.values():
        with pytest.raises(ValueError, match="voltage is constant"):
            model.fit(d, np.full_like(v, 3.0), n_operators=5)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_every_model_has_the_same_contract_on_bipolar_input(name):
    d, v = bipolar_loop()
    cls = MODELS[name]
    assert cls.name == name
    model = cls.fit(d, v, n_operators=8)
    assert model.predict(d).shape == d.shape
    prediction = model.predict(list(d))  # array_like
    assert np.all(np.isfinite(prediction))
    assert rms(prediction[200:] - v[200:]) < 0.05 * np.ptp(v), "does not follow a bipolar loop"
    json.dumps(model.params())
    with pytest.raises(AttributeError):  # frozen
        model.h0 = 1.0
    # predict starts from the eq. (4) state: predicting a prefix gives the prefix of the prediction
    np.testing.assert_allclose(model.predict(d[:150]), prediction[:150], rtol=0, atol=1e-9)


# ---------------------------------------------------------------- IIAPI (three-step, Fig. 3a)

def test_invert_pi_inverts_the_loading_curve():
    r = np.array([0.0, 1.0, 2.5, 4.0])
    a = np.array([1.0, 0.5, -0.3, 0.2])
    r_hat, a_hat = invert_pi(r, a)
    s = np.linspace(0, 8, 101)
    phi = np.maximum(s[:, None] - r, 0) @ a
    np.testing.assert_allclose(np.maximum(phi[:, None] - r_hat, 0) @ a_hat, s, atol=1e-12)
    with pytest.raises(ValueError, match="cumulative slopes"):
        invert_pi(r, np.array([1.0, -1.5, 0.0, 0.0]))


def test_monotone_clipping_rule():
    a, clipped = monotone_weights(np.array([1.0, -1.5, 2.0, 0.0]))
    assert clipped == 1
    assert np.all(np.cumsum(a) >= 1e-3 * np.cumsum(a).max() - 1e-15)
    np.testing.assert_allclose(np.cumsum(a), [1.0, 1.5e-3, 1.5, 1.5])
    with pytest.raises(ValueError, match="no positive"):
        monotone_weights(np.array([-1.0, 0.0]))


def positive_plant(v):
    """Forward play-operator plant, V → m (the paper's positive drive)."""
    return play(v, np.array([0.0, 5, 15, 30]), 0.0) @ np.array([0.6, 0.15, 0.1, 0.05]) * 1e-6


@pytest.mark.parametrize("n_operators", [3, 10])
def test_iiapi_inverse_composed_with_forward_is_identity_on_a_loop(n_operators):
    v_id = 50 + 50 * np.sin(np.linspace(-np.pi / 2, 5.5 * np.pi, 600))
    model = IIAPI.fit(positive_plant(v_id), v_id, n_operators=n_operators)
    assert model.n_clipped == 0
    d = reversals(np.array([30, 10, 28, 5, 20, 12, 30]) * UM, start=0.5 * UM)  # nested minor loops
    back = model.forward(model.predict(d))
    assert rms(back - d) < 0.01 * np.ptp(d)
    # the symmetric case is exact: same weights on both branches
    sym = IIAPI(model.widths, model.forward_trace, model.forward_trace, model.widths_inv_trace,
                model.weights_inv_trace, model.widths_inv_trace, model.weights_inv_trace, model.v_offset,
                model.bias, model.h0)
    np.testing.assert_allclose(sym.forward(sym.predict(d)), d, rtol=0, atol=1e-12 * np.ptp(d) + 1e-18)
    v = 40 + 30 * np.sin(np.linspace(0, 7 * np.pi, 500))
    np.testing.assert_allclose(sym.predict(sym.forward(v)), v, rtol=0, atol=1e-9)
    assert set(model.inverse_params) >= {"widths_trace_m", "weights_trace_V_per_m", "widths_retrace_m"}


# ---------------------------------------------------------------- CAPI (afmsim's continuous asymmetric PI)

@pytest.mark.parametrize("n_operators", [5, 10])
def test_capi_beats_diapi_on_a_synthetic_asymmetric_loop(n_operators):
    d, v = bipolar_loop(n_cycles=6)
    train = slice(0, 600)
    held = slice(600, None)  # the last three periods, predicted continuing from the first sample
    errors = {}
    for cls in (SPI, DIAPI, CAPI):
        model = cls.fit(d[train], v[train], n_operators=n_operators)
        errors[cls.name] = rms(model.predict(d)[held] - v[held])
    assert errors["capi"] < 0.9 * errors["diapi"], errors
    assert errors["capi"] < 0.9 * errors["spi"], errors


def test_capi_is_continuous_at_reversals_where_diapi_jumps():
    """On a finely sampled loop CAPI's step at a turn shrinks with the sampling; DIAPI's does not."""
    d, v = bipolar_loop(n_cycles=3)
    capi, diapi = CAPI.fit(d, v, 10), DIAPI.fit(d, v, 10)
    fine_d, fine_v = bipolar_loop(n_cycles=2, samples=20000)
    turns = np.flatnonzero(np.diff(branch_signs(fine_d)) != 0)
    typical = np.median(np.abs(np.diff(fine_v)))
    assert np.max(np.abs(np.diff(capi.predict(fine_d))[turns])) < 3 * typical
    assert np.max(np.abs(np.diff(diapi.predict(fine_d))[turns])) > 3 * typical


def test_capi_options_and_params():
    d, v = bipolar_loop()
    model = CAPI.fit(d, v, n_operators=6, spacing="eq5", degree=2, poly_degree=4)
    params = model.params()
    assert params["degree"] == 2 and params["poly_degree"] == 4
    assert len(params["curvature_V_per_m"]) == 5 and len(params["poly_V"]) == 5
    np.testing.assert_allclose(CAPI.fit(d, v, 10).widths, (np.arange(10) / 10) ** 2 * np.ptp(d))
    with pytest.raises(ValueError, match="spacing"):
        CAPI.fit(d, v, spacing="log")
    with pytest.raises(ValueError, match="degree"):
        CAPI.fit(d, v, degree=0)
