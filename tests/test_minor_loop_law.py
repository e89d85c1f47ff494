"""afmsim.diagnosis.loops.minor_loop names the minor-loop law a record supports, on held-out data.

Records are simulated from each law with the other law's code absent from the generator, by two
generators per law: the afmsim stage with all its physics (creep, drift, amplifier, resonance,
sensor noise) and an independent implementation (Preisach law: a Prandtl–Ishlinskii sum of play
operators from afmsim.hysteresis — a Preisach model with a width-only density; Duhem law: the
classic Coleman–Hodgdon equation with a constant α, integrated by scipy's solve_ivp). Seeds here
were not used while developing (development: seeds 0 and 1 on the stage generators).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from afmsim.diagnosis.engine import noise_floor
from afmsim.diagnosis.loops.minor_loop import interior_reversals, minor_loop_excitation, minor_loop_law
from afmsim.diagnosis.loops.record import load_record


def _stage_record(law, seed):
    from afmsim.stage import default_stage

    t, v = minor_loop_excitation(cycles=1)
    stage = default_stage(law)
    x, _ = stage.move(t, v, np.zeros_like(v))
    return t, v, stage.x.measure(x, np.random.default_rng(seed))


def _play_sum_record(seed):
    """Preisach law from other code: x = Σ w_k·play_k(v) (positive weights, widths up to 4 V)."""
    from afmsim.hysteresis import play

    t, v = minor_loop_excitation(cycles=1)
    widths = np.linspace(0.0, 4.0, 9)
    weights = 11e-6 * np.r_[0.8, np.full(8, 0.03)]
    x = play(v, widths, h0=0.0) @ weights
    return t, v, x + 10e-9 * np.random.default_rng(seed).standard_normal(x.size)


def _coleman_hodgdon_record(seed):
    """Duhem law from other code: dx/dv = g + σ·α·(f(v) − x), f = s·v·(1 + 0.04·v), g = 0.75·s, α = 0.5/V."""
    t, v = minor_loop_excitation(cycles=1)
    s, alpha = 10e-6, 0.5
    x = np.zeros_like(v)
    turns = np.r_[0, np.flatnonzero(np.diff(np.sign(np.diff(v))) != 0) + 1, v.size - 1]
    for a, b in zip(turns[:-1], turns[1:]):
        sigma = np.sign(v[b] - v[a])
        rhs = lambda u, y: [0.75 * s + sigma * alpha * (s * u * (1 + 0.04 * u) - y[0])]  # noqa: E731
        sol = solve_ivp(rhs, (v[a], v[b]), [x[a]], t_eval=v[a:b + 1], rtol=1e-9, atol=1e-15)
        x[a:b + 1] = sol.y[0]
    return t, v, x + 10e-9 * np.random.default_rng(seed).standard_normal(x.size)


GENERATORS = {
    "preisach-stage": ("preisach", lambda seed: _stage_record("preisach", seed)),
    "preisach-play-sum": ("preisach", _play_sum_record),
    "duhem-stage": ("duhem", lambda seed: _stage_record("duhem", seed)),
    "duhem-coleman-hodgdon": ("duhem", _coleman_hodgdon_record),
}


def _diagnose(t, v, x):
    rec = load_record((t, v, x))
    train = np.arange(rec.n) < int(round(0.6 * rec.n))
    return minor_loop_law(rec.t, rec.v, rec.x, train, noise_floor(rec.x))


@pytest.mark.parametrize("generator", GENERATORS)
def test_names_the_law_that_generated_the_record(generator):
    law, make = GENERATORS[generator]
    result = _diagnose(*make(seed=4242))
    gaps = result["heldout_rms_gap"]
    assert result["law"] == law, result["note"]
    other = "duhem" if law == "preisach" else "preisach"
    assert gaps[other] > 1.15 * gaps[law]


def test_a_single_loop_record_cannot_decide():
    """The paper's identification record (one 0 → 9.1 V loop, repeated) has no minor loops."""
    from afmsim.stage import default_stage, identification_experiment

    rec = identification_experiment(default_stage("duhem"), np.random.default_rng(7), cycles=3)
    assert interior_reversals(rec.voltage) == 0
    result = _diagnose(rec.t, rec.voltage, rec.displacement)
    assert result["law"] is None and "minor loops" in result["note"]
    assert result["heldout_rms_gap"] == {}


def test_the_excitation_holds_minor_loops_and_repeats_its_range_after_training():
    t, v = minor_loop_excitation()
    assert interior_reversals(v) >= 16
    train = t < 0.6 * t[-1]
    assert v[~train].max() <= v[train].max() and v[~train].min() >= v[train].min()
    with pytest.raises(ValueError, match="amplitudes_V"):
        minor_loop_excitation(amplitudes_V=(5.0,), centre_V=4.55)
