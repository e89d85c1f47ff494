"""Null records from hysteresis families other than the baseline's (issue 11, point 3).

The generators (:mod:`afmsim.diagnosis.loops.null_plants`) are checked to be rate-independent and
hysteretic; the diagnosis of their records (no added effect) must name no effect and — the
target, not met yet — should find nothing missing. Seed 2026 was not used while developing the
baseline (development seeds: 100–103); its scattered-Preisach record's false drift (held-out
shrink 14 %, training RMS unchanged) prompted the training-support rule of the attribution
(:attr:`afmsim.diagnosis.engine.Rules.training_support`), so that record is a regression check of
the rule now, not evidence for it (the open-world suite's fresh seeds are).
"""

import numpy as np
import pytest

from afmsim.diagnosis import diagnose_loops
from afmsim.diagnosis.loops.null_plants import NULL_FAMILIES, OTHER_FAMILIES, _relay_sum, null_plant
from afmsim.diagnosis.loops.validation import excitation

FRESH_SEED = 2026


def _triangles(points_per_edge):
    """A 0–10 V triangle path through fixed vertices, sampled ``points_per_edge`` per edge."""
    vertices = [0.0, 8.0, 2.0, 9.5, 4.0, 6.0, 1.0, 9.0, 0.5]
    edges = [np.linspace(a, b, points_per_edge, endpoint=False) for a, b in zip(vertices[:-1], vertices[1:])]
    return np.r_[np.concatenate(edges), vertices[-1]]


@pytest.mark.parametrize("family", sorted({**NULL_FAMILIES, **OTHER_FAMILIES}))
def test_null_plants_are_rate_independent_and_hysteretic(family):
    slow, fast = _triangles(400), _triangles(100)  # the same voltage path, four times fewer samples
    x_slow = null_plant(family, slow, np.random.default_rng(1))
    x_fast = null_plant(family, fast, np.random.default_rng(1))
    assert np.ptp(x_slow) == pytest.approx(100e-6, rel=1e-9)
    # the same path gives the same displacement at the shared samples (Bouc–Wen: integration error only)
    assert np.max(np.abs(x_slow[::4] - x_fast)) < 2e-3 * np.ptp(x_slow)
    # rising (0 → 8 V) and falling (8 → 2 V) branches differ at 5 V by more than 1 % of the travel
    up = np.interp(5.0, slow[:400], x_slow[:400])
    down = np.interp(-5.0, -slow[400:800], x_slow[400:800])
    assert abs(down - up) > 0.01 * np.ptp(x_slow)


@pytest.fixture(scope="module")
def null_reports():
    out = {}
    for family in sorted(NULL_FAMILIES):
        rng = np.random.default_rng([FRESH_SEED, len(out)])
        t, v = excitation("sines", 1000.0, 12.0, rng)
        x = null_plant(family, v, rng) + 8e-9 * rng.standard_normal(t.size)
        out[family] = diagnose_loops({"t_s": t, "v_V": v, "x_m": x})[0]
    return out


def test_a_bouc_wen_null_gets_the_bouc_wen_baseline_and_nothing_missing(null_reports):
    rep = null_reports["bouc_wen"]
    assert rep["baseline"]["family"] == "bouc_wen"
    assert rep["status"] == "nothing_missing" and rep["baseline"]["gap_to_noise"] <= 2.0


def test_no_effect_is_named_on_a_null_of_another_family(null_reports):
    for family, rep in null_reports.items():
        assert rep["verdict"] == [], family
        if rep["status"] == "nothing_missing":
            assert rep["baseline"]["gap_to_noise"] <= 2.0, family


def test_the_scattered_null_drift_shrinks_the_held_out_gap_but_not_the_training_part(null_reports):
    """The drift that this record once got named: it still passes the held-out tests, and the
    training part refuses it (training ΔBIC > 0), which the report shows."""
    drift = next(e for e in null_reports["scattered_preisach"]["effects"] if e["name"] == "drift")
    assert drift["heldout_shrink"] > 0.05 and not drift["significant"]
    assert drift["test"]["delta_bic"] < -6 and drift["test"]["blocks_improved"] >= 0.7  # held out: would pass
    assert drift["test"]["train_delta_bic"] > 0


@pytest.mark.xfail(strict=True, reason="issue 11.3 not met: the baseline (32-level relay grid with its density prior, "
                                       "the Bouc-Wen law or fine play operators, chosen by generalised cross-validation "
                                       "on the training part; held-out scoring in trained relay states) leaves 4.2x "
                                       "(generalised PI) and 2.1x (scattered Preisach) the noise floor on fresh seed "
                                       "2026; Bouc-Wen is within (0.99x) "
                                       "(see docs/diagnosis.md, 'Status and honesty')")
def test_other_hysteresis_families_come_out_nothing_missing(null_reports):
    gaps = {family: rep["baseline"]["gap_to_noise"] for family, rep in null_reports.items()}
    assert all(g <= 2.0 for g in gaps.values()), gaps


def test_the_bouc_wen_plant_resolves_a_voltage_jump():
    """A 7 V jump in one sample gives the displacement of the same move spread over 700 samples
    (with a fixed 8 substeps per sample, as before, they differed by 35 µm, a third of the travel)."""
    jump = np.r_[np.zeros(10), np.full(10, 7.0), np.full(10, 2.0)]
    ramp = np.r_[np.zeros(10), np.linspace(0.0, 7.0, 701)[1:], np.full(10, 7.0), np.linspace(7.0, 2.0, 501)[1:], np.full(10, 2.0)]
    x_jump = null_plant("bouc_wen", jump, np.random.default_rng(3))  # both paths span 0-7 V: the same
    x_ramp = null_plant("bouc_wen", ramp, np.random.default_rng(3))  # travel normalisation
    assert abs(x_jump[15] - x_ramp[715]) < 5e-5 * np.ptp(x_ramp)  # 5 nm of 100 µm
    assert abs(x_jump[-1] - x_ramp[-1]) < 5e-5 * np.ptp(x_ramp)


def _relay_sum_by_definition(v, up, down, weight):
    """Each relay stepped through every sample: on where v ≥ up, off where v ≤ down, else held."""
    out = np.zeros(v.size)
    for a, b, w in zip(up, down, weight):
        on = v[0] >= a
        for k, u in enumerate(v):
            on = True if u >= a else False if u <= b else on
            out[k] += w * on
    return out


def test_the_sorted_relay_sum_switches_every_relay_as_defined():
    """The scattered plant's kernel visits only the relays whose thresholds a sample crosses; on a
    voltage lattice that the thresholds share (samples landing exactly on them, repeated values)
    it must switch each relay as the definition does."""
    rng = np.random.default_rng(7)
    for _ in range(5):
        v = np.round(rng.uniform(0.0, 10.0, 400) * 4) / 4
        up = np.round(rng.uniform(-1.0, 11.0, 200) * 4) / 4
        down = up - np.round(rng.uniform(0.25, 3.0, 200) * 4) / 4
        weight = rng.uniform(0.0, 1.0, 200)
        np.testing.assert_allclose(_relay_sum(v, up, down, weight), _relay_sum_by_definition(v, up, down, weight), atol=1e-9)
