"""Setting the plant's skew from a measured loop's shape (afmsim.stage.loop_shape)."""

from pathlib import Path

import numpy as np
import pytest

from afmsim.stage import AsymmetricDuhem, AsymmetricPreisach
from afmsim.stage.loop_shape import mean_cycle, skew_from_loop

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real-data" / "piezo-sine-150V-1Hz.csv"


@pytest.mark.parametrize("model, true_skew", [(AsymmetricPreisach(), 0.35), (AsymmetricDuhem(), -0.55)])
def test_recovers_the_skew_of_a_simulated_bipolar_sine_record(model, true_skew):
    """A ±150 V, 1 Hz sine 'measured' on a plant of known skew (other units, offset, noise): the
    fit finds that skew back on its grid."""
    from dataclasses import replace

    t = np.arange(0, 6.0, 2e-4)
    v = 150.0 * np.sin(2 * np.pi * t - np.pi / 2)
    plant = replace(model, skew=true_skew)
    u = (v + 150.0) / 300.0 * plant.calibration_amplitude_V
    x = 40e-6 * plant.apply(u) / plant.apply(u).max() - 20e-6
    x += 5e-9 * np.random.default_rng(3).standard_normal(x.size)
    v_cycle, x_cycle = mean_cycle(t, v, x, period_s=1.0, start_s=2.0)
    skew, errors = skew_from_loop(model, v_cycle, x_cycle, skews=np.linspace(-1, 1, 41))
    assert skew == pytest.approx(true_skew, abs=0.051)
    assert errors[skew] < 0.2 * max(errors.values())


def test_mean_cycle_rejects_a_record_without_a_whole_period():
    t = np.linspace(0, 1.5, 1000)
    with pytest.raises(ValueError, match="no whole period"):
        mean_cycle(t, np.sin(t), t, period_s=1.0, start_s=1.0)


@pytest.mark.skipif(not REAL.exists(), reason="../shared/real-data not present")
def test_the_real_piezo_loop_is_nearly_centrally_symmetric():
    """The real record (a ±150 V bipolar sine) gives the Preisach plant no asymmetry: skew 0 fits
    its shape best — far from the Table 2 calibration 0.6 (docs/reference-results.md)."""
    t, v, x = np.genfromtxt(REAL, delimiter=",", skip_header=1).T
    v_cycle, x_cycle = mean_cycle(t, v, x, period_s=1.0, start_s=4.0)
    skew, errors = skew_from_loop(AsymmetricPreisach(), v_cycle, x_cycle, skews=np.linspace(-1, 1, 21))
    assert abs(skew) <= 0.1
    assert errors[0.6] > 1.5 * errors[skew]
