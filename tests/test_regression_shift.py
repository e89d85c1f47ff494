"""Image-shift regression: a small scenario's trace/retrace shifts pinned against the stored baseline.

A physics change that moves these figures fails here loudly; if the change is intended, run
``python tests/regression/regenerate.py`` and explain the new values in the commit.
"""

import json
from pathlib import Path

import pytest

from afmsim.experiment import run_scenario
from afmsim.scenario import load_scenario

HERE = Path(__file__).resolve().parent / "regression"


@pytest.fixture(scope="module")
def measured():
    return run_scenario(load_scenario(HERE / "shift_scenario.yaml")).metrics()["controllers"]


@pytest.fixture(scope="module")
def baseline():
    path = HERE / "shift_baseline.json"
    assert path.exists(), f"missing committed baseline {path}: run tests/regression/regenerate.py"
    return json.loads(path.read_text())


@pytest.mark.parametrize("controller", ["none", "spi", "diapi", "ideal"])
def test_shift_and_nsl2_match_the_baseline(measured, baseline, controller):
    stored, tol = baseline["controllers"][controller], baseline["tolerances"]
    assert measured[controller]["shift_x_m"]["mean"] == pytest.approx(stored["shift_x_m"], abs=tol["shift_x_m_abs"])
    assert measured[controller]["nsl2"]["mean"] == pytest.approx(stored["nsl2"], rel=tol["nsl2_rel"])


def test_uncompensated_shift_is_hysteresis_sized_and_compensation_reduces_it(measured):
    shift = {name: abs(c["shift_x_m"]["mean"]) for name, c in measured.items()}
    assert 0.3e-6 < shift["none"] < 4e-6                      # a few % of a 24 µm scan
    assert shift["spi"] < shift["none"] and shift["diapi"] < shift["none"]
    assert shift["ideal"] < 0.05e-6                           # no piezo memory: only Z-loop lag is left
    assert measured["ideal"]["nsl2"]["mean"] < min(c["nsl2"]["mean"] for n, c in measured.items() if n != "ideal")
