"""Cross-coupling x → y as an output of the loop diagnosis: the y axis is not driven, so y following x
is coupling. Records come from the simulator's own XY stage (its coupling code, Preisach plant,
creep, sensor noise) — not from the estimator's equation."""

from dataclasses import replace

import numpy as np
import pytest

from afmsim.diagnosis.loops.coupling import coupling_output, coupling_text
from afmsim.stage import default_stage, triangle_wave


def _record(coupling: float, seed: int, drift: bool = False):
    stage = replace(default_stage().with_effects(coupling=coupling > 0, drift=drift), coupling_x_to_y=coupling)
    t, v = triangle_wave(9.1, 1.0, 1000.0, cycles=4)
    x, y = stage.move(t, v, np.zeros_like(v))
    xm, ym = stage.measure(x, y, np.random.default_rng(seed))
    return t, xm, ym


@pytest.mark.parametrize("kappa", [0.002, 0.01])
def test_datasheet_sized_coupling_is_recovered_from_the_undriven_axis(kappa):
    t, x, y = _record(kappa, seed=31)
    train = np.arange(t.size) < int(0.6 * t.size)
    block = coupling_output(t, x, y, train)
    assert block["detected"] and not block["implausible"]
    assert block["kappa"] == pytest.approx(kappa, rel=0.1)
    assert block["kappa_se"] < 0.1 * kappa and block["heldout_shrink"] > 0.5
    assert coupling_text(block).endswith("y follows x.")


def test_no_coupling_with_drift_is_not_detected():
    t, x, y = _record(0.0, seed=32, drift=True)
    block = coupling_output(t, x, y, np.arange(t.size) < int(0.6 * t.size))
    assert not block["detected"] and abs(block["kappa"]) < 5 * block["kappa_se"] + 1e-4
    assert coupling_text(block).endswith("not detected.")


def test_y_that_follows_x_by_far_more_than_a_stage_couples_is_flagged_implausible():
    t, x, _ = _record(0.0, seed=33)
    y = 0.2 * x + np.random.default_rng(34).normal(0, 5e-9, x.size)      # e.g. a y drive that was not held
    block = coupling_output(t, x, y, np.arange(t.size) < int(0.6 * t.size))
    assert block["detected"] and block["implausible"] and block["implausible"][0]["parameter"] == "coefficient"
    assert "IMPLAUSIBLE" in coupling_text(block)


def test_the_loop_diagnosis_reports_kappa_in_its_json_and_summary():
    from afmsim.diagnosis import diagnose_loops

    t, x, y = _record(0.005, seed=35)
    rep, summary = diagnose_loops({"t_s": t, "v_V": triangle_wave(9.1, 1.0, 1000.0, cycles=4)[1], "x_m": x, "y_m": y})
    block = rep["cross_coupling_output"]
    assert block["detected"] and block["kappa"] == pytest.approx(0.005, rel=0.1)
    assert "Cross-coupling x → y: κ = +0.5" in summary
