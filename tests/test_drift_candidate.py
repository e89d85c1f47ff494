"""The loop ``drift`` candidate: a parabola in time on the training part, continued at its final slope."""

import numpy as np
from scipy.signal import butter, sosfiltfilt

import afmsim.diagnosis.loops.alike as alike
import afmsim.diagnosis.loops.model as model
import afmsim.diagnosis.loops.open_world as open_world
import afmsim.diagnosis.loops.validation as validation
from afmsim.diagnosis.loops.alike import (SENSITIVITY_ALIKE, SENSITIVITY_DELTA_BIC, SLIP_ALIKE,
                                          rival_over_term_delta_bic, scales_with_displacement,
                                          sensitivity_delta_bic, slip_instant, steps_in_time)
from afmsim.diagnosis.loops.attribute import diagnose_record
from afmsim.diagnosis.loops.model import drift_curvature_column
from afmsim.diagnosis.loops.open_world import case_plan, make_case
from afmsim.diagnosis.loops.record import load_record


def test_the_curvature_column_is_a_parabola_on_the_training_part_and_straight_beyond():
    tn = np.linspace(0.0, 1.0, 101)
    train = tn <= 0.6
    col = drift_curvature_column(tn, train)
    assert np.array_equal(col[train], tn[train] ** 2)
    beyond = np.diff(col[~train]) / np.diff(tn[~train])
    assert np.allclose(beyond, 2 * 0.6)  # the parabola's slope at the last training sample
    assert col[-1] < 1.0  # where the parabola would have reached 1
    interior = ~((tn > 0.3) & (tn < 0.5))  # a held-out block between training parts
    assert np.array_equal(drift_curvature_column(tn, interior), tn**2)


def _walk_scaled_to_its_least_squares_rate(t, rate, form, rng):
    """The suite's drift before 43001–43003, for the records generated with it: a walk scaled so that
    its least-squares slope is ``rate`` (the same draws as :func:`open_world.drift_term`)."""
    if form != "walk":
        return open_world.drift_term(t, rate, form, rng)
    s = t - t[0]
    sos = butter(2, min(rng.uniform(3.0, 10.0) / s[-1], 0.4 / s[1]), fs=1.0 / s[1], output="sos")
    shape = np.cumsum(sosfiltfilt(sos, rng.standard_normal(s.size)))
    return shape * (rate * rng.choice([-1.0, 1.0]) / np.polyfit(s, shape, 1)[0])


def test_a_random_walk_is_named_drift_once_its_curvature_is_not_extrapolated(monkeypatch):
    """Spent open-world record 36003/2: a 40 nm/min smooth random walk on a scattered-Preisach stage
    under band-limited noise, 7.3× the noise held out. The parabola carried over the held-out part
    shrinks the gap by 22 % (ΔBIC −2.5 with its parameters charged); continued at its final slope, by
    35 % (−8.7). Both pass the plain held-out likelihood ratio, so the continued form is pinned by what
    it forecasts: a larger share of the held-out gap. The record as the suite then made it (its walk
    scaled to a least-squares rate).
    The walk turns once in the training part, and a step there fits that part better than the drift
    (training ΔBIC −291 against it); it predicts the held-out part worse (27.1 nm RMS against the
    drift's 17.9 nm), so the drift is not taken for a slip (:func:`.alike.steps_in_time`)."""
    with monkeypatch.context() as patch:
        patch.setattr(open_world, "drift_term", _walk_scaled_to_its_least_squares_rate)
        case = make_case(case_plan()[2], np.random.default_rng([36003, 2]))
    assert [e["form"] for e in case["injected"]] == ["walk"]
    rec = load_record(case["columns"])
    continued, _, _ = diagnose_record(rec, candidates=["drift"])
    assert continued["verdict"] == ["drift"], continued["effects"]
    assert continued["final"]["gap_to_noise"] < 0.7 * continued["baseline"]["gap_to_noise"]
    monkeypatch.setattr(model, "drift_curvature_column", lambda tn, train: tn**2)
    parabola, _, _ = diagnose_record(rec, candidates=["drift"])
    assert parabola["effects"][0]["heldout_shrink"] < 0.7 * continued["effects"][0]["heldout_shrink"]


def _triangle_record(seed):
    """60 s of a 0.5 Hz triangle over 100 µm at 100 Hz, with 5 nm of sensor noise (m)."""
    t = np.arange(6000) / 100.0
    x = 100e-6 * (1.0 - np.abs(2.0 * ((0.5 * t) % 1.0) - 1.0))
    return t, x, 5e-9 * np.random.default_rng(seed).standard_normal(t.size)


def test_a_residual_that_scales_with_the_displacement_reads_as_a_sensitivity_change():
    t, x, noise = _triangle_record(0)
    train, everywhere = t < 36.0, np.ones(t.size, dtype=bool)
    ramp = np.clip((t - 20.0) / 20.0, 0.0, 1.0)
    gain = sensitivity_delta_bic(t, x + 0.005 * ramp * x + noise, x, x, train, everywhere)
    drift = sensitivity_delta_bic(t, x + 60e-9 * ramp + noise, x, x, train, everywhere)  # an additive warm-up
    assert gain < SENSITIVITY_DELTA_BIC < drift
    assert scales_with_displacement(t, x + 0.005 * ramp * x + noise, x, x, train, everywhere)
    assert not scales_with_displacement(t, x + 60e-9 * ramp + noise, x, x, train, everywhere)


def _train_fit(columns, r, train):
    """Residuals (m) of ``r`` after a least-squares fit of ``columns`` on the ``train`` samples: on
    the training part and beyond it."""
    coef, *_ = np.linalg.lstsq(columns[train], r[train], rcond=None)
    rest = r - columns @ coef
    return rest[train], rest[~train]


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


def test_a_step_in_time_is_told_from_a_drift_of_the_same_size():
    """A 40 nm slip at 22 s and drifts that cover 40 nm over the record (a steady one, a warm-up) on
    the same triangle record: the slip's instant is found, and a step there fits the slip better
    than the drift's time columns do and predicts the rest better; for the drifts the step is the
    worse fit. (A drift that turns once, as a step does, and goes on wandering: the random walk of
    36003/2 below, which a step fits better on the training part and predicts worse beyond it.)"""
    t, x, noise = _triangle_record(1)
    train = t < 36.0
    tn = t / t[-1]
    drift_cols = np.column_stack([np.ones(t.size), tn, drift_curvature_column(tn, train)])
    for change, is_slip in ((np.where(t >= 22.0, 40e-9, 0.0), True), (40e-9 * tn, False),
                            (40e-9 * -np.expm1(-t / 30.0) / -np.expm1(-2.0), False)):
        at = slip_instant(t, x + change + noise, x, x, train)
        r = change + noise
        r_drift, held_drift = _train_fit(drift_cols, r, train)
        r_step, held_step = _train_fit(np.column_stack([np.ones(t.size), t >= at]), r, train)
        delta = rival_over_term_delta_bic(r[train] - r[train].mean(), r_drift, r_step, 2, 2)
        assert steps_in_time(delta, _rms(held_step), _rms(held_drift)) == is_slip, (at, delta)
        if is_slip:
            assert abs(at - 22.0) < 0.2


def test_a_drift_standing_in_for_a_slip_is_reported_not_named():
    """Spent open-world record 56001/28: a 40 nm slip at 22.4 s of a 43.6 s record of steps on a
    Bouc–Wen stage — inside the training part — that the drift took to ``explained`` (6.3× → 1.05×)
    before a step in time competed with it (training ΔBIC −20 against the drift, both refitted with
    the hysteresis). The drift is reported, not named, with the step the record shows."""
    case = make_case(case_plan()[28], np.random.default_rng([56001, 28]))
    (slip,) = case["injected"]
    assert slip["distractor"] == "slip"
    rep, summary, _ = diagnose_record(load_record(case["columns"]))
    assert "drift" not in rep["verdict"] and rep["status"] != "explained"
    (caveat,) = [c for c in rep["caveats"] if c["effect"] == "drift"]
    assert caveat["kind"] == "step_in_time" and caveat["alike"] == SLIP_ALIKE and caveat["step_delta_bic"] < 0
    assert caveat["step_heldout_rms_m"] <= caveat["drift_heldout_rms_m"]
    assert abs(caveat["step_at_s"] - slip["at_s"]) < 0.5 and abs(abs(caveat["step_m"]) - slip["value"]) < 0.3 * slip["value"]
    assert "Not named: drift" in summary and "a step of" in summary


def test_a_drift_standing_in_for_a_sensor_gain_ramp_is_reported_not_named():
    """Spent open-world record 45003/31: a sensor whose sensitivity ramps by 2 % during the record
    (a distractor, not a candidate) on a Bouc–Wen stage under triangles, read as an implausible drift
    before (sensitivity ΔBIC −249). Record 45002/3, a true 90 nm/min drift on a scattered-Preisach
    stage under sines, still names it (explained)."""
    case = make_case(case_plan()[31], np.random.default_rng([45003, 31]))
    assert [e.get("distractor") for e in case["injected"]] == ["gain_change"]
    rep, summary, _ = diagnose_record(load_record(case["columns"]))
    assert "drift" not in rep["verdict"] and rep["status"] != "explained"
    (caveat,) = [c for c in rep["caveats"] if c["effect"] == "drift"]
    assert caveat["kind"] == "scales_with_displacement" and not caveat["named"] and caveat["alike"] == SENSITIVITY_ALIKE
    assert "Not named: drift" in summary
    drift = make_case(case_plan()[3], np.random.default_rng([45002, 3]))
    assert [e["effect"] for e in drift["injected"]] == ["drift"]
    rep, _, _ = diagnose_record(load_record(drift["columns"]))
    assert rep["verdict"][:1] == ["drift"] and not any(c["effect"] == "drift" for c in rep["caveats"])


def test_a_large_warm_up_drift_is_not_read_as_a_sensitivity_change(monkeypatch):
    """The closed suite's largest drift (``validate-diagnosis`` seed 0, its ``("drift", 2)`` case: an
    exponential warm-up of 6 % of the travel on afmsim's stage under noise). The parabola leaves a
    smooth remainder in time that the displacement's slow wander can take: without the smooth term
    (``SMOOTH_DEGREE = 0``) the drift read as a sensitivity change and was withheld. The record
    prompted the smooth term, so this is a regression check, not evidence."""
    plan = validation.case_plan(30)
    draws = np.random.default_rng(0).integers(2**63, size=len(plan))
    spec = ("drift", 2)
    case = validation.make_case(spec, np.random.default_rng(int(draws[plan.index(spec)])))
    rec = load_record(case["columns"])
    rep, _, _ = diagnose_record(rec)
    assert "drift" in rep["verdict"] and not any(c["effect"] == "drift" for c in rep["caveats"])
    monkeypatch.setattr(alike, "SMOOTH_DEGREE", 0)
    rep, _, _ = diagnose_record(rec)
    assert "drift" not in rep["verdict"] and [c["kind"] for c in rep["caveats"]] == ["scales_with_displacement"]
