"""The two minor-loop laws of the plant: properties that hold for both, and the one that defines each.

* Both: loops close (a cycle back to 0 V ends at 0; periodic inputs settle on a closed loop) and the
  output depends on the input path only (rate independence: resampling the path changes nothing).
* Preisach (state-bound minor loops): wiping-out and congruency of minor loops with the same extrema.
* Duhem (direction-bound minor loops): the branch slope is the Duhem law of the direction and the
  distance to the anhysteretic line, whatever the history; no return-point memory, no congruency.
"""

from __future__ import annotations

import numpy as np
import pytest

from afmsim.stage import AsymmetricDuhem, AsymmetricPreisach

MODELS = {"preisach": AsymmetricPreisach(), "duhem": AsymmetricDuhem()}
TRAVEL = 100e-6


def path(*turning_points, step=0.01):
    """Piecewise-linear input (V) through the turning points, ``step`` V apart at most."""
    pieces = [np.array([turning_points[0]], dtype=float)]
    for a, b in zip(turning_points[:-1], turning_points[1:]):
        n = max(1, int(np.ceil(abs(b - a) / step)))
        pieces.append(np.linspace(a, b, n + 1)[1:])
    return np.concatenate(pieces)


def ends(*turning_points):
    """Indices of the turning points in :func:`path` of the same points."""
    index = [0]
    for a, b in zip(turning_points[:-1], turning_points[1:]):
        index.append(index[-1] + max(1, int(np.ceil(abs(b - a) / 0.01))))
    return np.array(index)


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("amplitude", [1.0, 4.0, 9.1])
def test_a_cycle_from_rest_closes_at_zero_volts(name, amplitude):
    y = MODELS[name].apply(path(0.0, amplitude, 0.0))
    assert y.max() > 5e-6
    assert abs(y[-1]) < 1e-9 * TRAVEL


@pytest.mark.parametrize("name", MODELS)
def test_periodic_input_settles_on_a_closed_loop(name):
    """After an arbitrary history, cycling between 3 and 7 V converges: the end-of-cycle output
    changes less and less and the loop closes (no ratchet, unlike an unclosed Bouc–Wen loop)."""
    points = [0.0, 9.0, 1.5, 5.0] + [3.0, 7.0] * 8
    u = path(*points)
    y = MODELS[name].apply(u)
    at_seven = y[ends(*points)[5::2]]  # the output each time the input is back at 7 V
    steps = np.abs(np.diff(at_seven))
    assert steps[-1] < 1e-6 * TRAVEL
    assert np.all(steps[1:] <= steps[:-1] + 1e-12 * TRAVEL)


@pytest.mark.parametrize("name", MODELS)
def test_rate_independence_resampled_path(name):
    """The same turning points, sampled uniformly or at random steps: the same output at every
    turning point (the plant sees the path, not the speed along it)."""
    points = (0.0, 8.0, 2.0, 6.5, 3.5, 9.1, 0.5)
    model = MODELS[name]
    fine = model.apply(path(*points))[ends(*points)]
    rng = np.random.default_rng(11)
    pieces, marks = [np.array([points[0]])], [0]
    for a, b in zip(points[:-1], points[1:]):
        inner = np.sort(rng.uniform(min(a, b), max(a, b), rng.integers(3, 40)))
        inner = inner if b > a else inner[::-1]
        pieces.append(np.r_[inner, b])
        marks.append(marks[-1] + inner.size + 1)
    coarse = model.apply(np.concatenate(pieces))[marks]
    np.testing.assert_allclose(coarse, fine, rtol=0, atol=1e-9 * TRAVEL)


def test_preisach_wiping_out_and_congruency():
    model = MODELS["preisach"]
    # wiping-out: a minor loop 6 → 4 → 6 inside the rise is erased once the input passes 6 V again
    direct = model.apply(path(0.0, 9.1))[-1]
    with_minor = model.apply(path(0.0, 6.0, 4.0, 9.1))[-1]
    assert abs(direct - with_minor) < 1e-12 * TRAVEL
    # congruency: the minor loop 6 → 4 → 6 after two different histories has the same shape
    a_points, b_points = (0.0, 9.0, 4.0, 6.0, 4.0, 6.0), (0.0, 6.0, 4.0, 6.0)
    a = model.apply(path(*a_points))[ends(*a_points)[3]:]
    b = model.apply(path(*b_points))[ends(*b_points)[1]:]
    assert abs(a[0] - b[0]) > 1e-6  # different histories: the loops sit at different heights ...
    np.testing.assert_allclose(a - a[0], b - b[0], rtol=0, atol=1e-12 * TRAVEL)  # ... with one shape


def test_duhem_branch_slope_is_set_by_direction_and_distance_to_anhysteretic_line():
    """dŷ/dx = g_σ(x) + σ·α(x)·(x − ŷ) on every branch, whatever the history that led there."""
    model = MODELS["duhem"]
    scale = model._scale
    points = (0.0, 9.1, 2.0, 7.0, 4.0, 8.5)
    u = path(*points, step=0.001)
    y = model.apply(u) / scale
    k = ends(*points) * 10  # step 0.001 V: ten times the indices of the 0.01 V path
    checked = 0
    for start, stop in zip(k[:-1], k[1:]):
        rising = u[stop] > u[start]
        for i in range(start + 200, stop - 200, 300):
            observed = (y[i + 1] - y[i - 1]) / ((u[i + 1] - u[i - 1]) / model.u_max_V)
            assert observed == pytest.approx(float(model.branch_slope(u[i], y[i], rising)), abs=1e-5)
            checked += 1
    assert checked > 40
    # the same (u, ŷ) with opposite directions gives different slopes: the direction binds the branch
    assert abs(float(model.branch_slope(5.0, 0.5, True)) - float(model.branch_slope(5.0, 0.5, False))) > 0.05


def test_duhem_has_no_return_point_memory_nor_congruency():
    """What separates the Duhem law from Preisach's (and from any PI model, which wipes out exactly)."""
    model = MODELS["duhem"]
    with_minor = model.apply(path(0.0, 6.0, 4.0, 6.0))[-1]
    assert abs(model.apply(path(0.0, 6.0))[-1] - with_minor) > 1e-3 * TRAVEL  # loop 6 → 4 → 6 stays open
    a_points, b_points = (0.0, 9.0, 4.0, 6.0, 4.0, 6.0), (0.0, 6.0, 4.0, 6.0)
    a = model.apply(path(*a_points))[ends(*a_points)[3]:]
    b = model.apply(path(*b_points))[ends(*b_points)[1]:]
    assert np.max(np.abs((a - a[0]) - (b - b[0]))) > 1e-3 * TRAVEL


def test_duhem_rising_branch_from_rest_is_the_lower_bounding_curve():
    """The compiled kernel and the band formula agree: from rest the output follows x − w(x)/2."""
    model = MODELS["duhem"]
    u = np.linspace(0.0, 10.0, 501)
    expected = (u / model.u_max_V - model.band(u) / 2) * model._scale
    np.testing.assert_allclose(model.apply(u), expected, rtol=0, atol=1e-12 * TRAVEL)


@pytest.mark.parametrize("bad", [dict(band_width=-0.1), dict(band_power=0.0), dict(relaxation_rate=-1.0),
                                 dict(u_max_V=0.0)])
def test_duhem_rejects_bad_parameters(bad):
    with pytest.raises(ValueError, match="band_width"):
        AsymmetricDuhem(**bad)
