"""Property tests of the backlash operators (paper eq. 2 and 4)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from afmsim.hysteresis import osp, osp_reference, play, play_reference

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
signals = arrays(np.float64, st.integers(1, 60), elements=finite)
width_sets = arrays(np.float64, st.integers(1, 8), elements=st.floats(0, 500, allow_nan=False))


@settings(max_examples=200, deadline=None)
@given(signals, width_sets, finite)
def test_compiled_osp_matches_numpy_reference(d, widths, h0):
    np.testing.assert_allclose(osp(d, widths, h0), osp_reference(d, widths, h0), rtol=0, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(signals, width_sets, finite)
def test_compiled_play_matches_numpy_reference(d, widths, h0):
    np.testing.assert_allclose(play(d, widths, h0), play_reference(d, widths, h0), rtol=0, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(signals, width_sets, finite)
def test_osp_output_stays_in_band(d, widths, h0):
    H = osp(d, widths, h0)
    assert np.all(H <= d[:, None] + 1e-12)
    assert np.all(H >= d[:, None] - widths[None, :] - 1e-12)


@settings(max_examples=200, deadline=None)
@given(signals, width_sets, finite)
def test_play_output_stays_in_band(d, widths, h0):
    P = play(d, widths, h0)
    assert np.all(np.abs(P - d[:, None]) <= widths[None, :] + 1e-9)


@settings(max_examples=100, deadline=None)
@given(signals, width_sets, st.integers(1, 7))
def test_rate_independence(d, widths, refine):
    """Sampling the same path more finely in time leaves the output at the old samples unchanged."""
    fine_index = np.arange((d.size - 1) * refine + 1) / refine
    d_fine = np.interp(fine_index, np.arange(d.size), d)
    H_fine = osp(d_fine, widths)
    np.testing.assert_allclose(H_fine[::refine], osp(d, widths), atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(signals, signals, width_sets, signals)
def test_wiping_out_after_a_dominant_excursion(history_a, history_b, widths, tail):
    """A swing below every past minimum and then above every past maximum by more than the
    widest operator erases the memory: two different histories give the same future."""
    low = min(history_a.min(), history_b.min()) - 1.0
    high = max(history_a.max(), history_b.max(), low + widths.max()) + 1.0
    swing = np.array([low, high])
    out_a = osp(np.concatenate([history_a, swing, tail]), widths)[-tail.size:]
    out_b = osp(np.concatenate([history_b, swing, tail]), widths)[-tail.size:]
    np.testing.assert_allclose(out_a, out_b, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(signals, width_sets, finite)
def test_osp_is_a_shifted_play_operator(d, widths, h0):
    """OSP of width r equals the play operator of half-width r/2 on the input shifted by r/2."""
    expected = np.column_stack([play(d - r / 2, [r / 2], h0)[:, 0] for r in widths])
    np.testing.assert_allclose(osp(d, widths, h0), expected, atol=1e-9)


def test_initial_state_follows_eq4_for_a_de_energised_actuator():
    widths = np.array([0.0, 2.0, 5.0])
    # d(0) = 3 >= h0 = 0: eq. (4) as printed, max{d0 - r, min[d0 + r, h0]}, gives the same state.
    H0 = osp([3.0], widths, h0=0.0)[0]
    np.testing.assert_array_equal(H0, np.maximum(3.0 - widths, np.minimum(3.0 + widths, 0.0)))
    np.testing.assert_array_equal(H0, [3.0, 1.0, 0.0])


def test_rejects_bad_arguments():
    with pytest.raises(ValueError, match="widths"):
        osp([0.0, 1.0], [-1.0])
    with pytest.raises(ValueError, match="1-D"):
        osp(np.zeros((2, 2)), [1.0])
