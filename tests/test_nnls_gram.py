"""The baseline's sign-constrained least squares (``afmsim.diagnosis.loops.nnls``): the bulk active
set reaches Lawson–Hanson's minimiser, mostly-positive or mostly-zero, and gives up where it cannot
certify one."""

import numpy as np
import pytest
from scipy.optimize import nnls

from afmsim.diagnosis.loops.nnls import nnls_gram


def _lawson_hanson(a, x, n_free):
    """The reference: scipy's Lawson–Hanson with the free weights split into ± pairs."""
    z, _ = nnls(np.hstack([a[:, :n_free], -a[:, :n_free], a[:, n_free:]]), x, maxiter=50 * (a.shape[1] + n_free))
    return np.r_[z[:n_free] - z[n_free:2 * n_free], z[2 * n_free:]]


@pytest.mark.parametrize("seed, positive_share", [(1, 0.9), (2, 0.5), (3, 0.1)])
def test_the_bulk_active_set_reaches_lawson_hansons_minimiser(seed, positive_share):
    rng = np.random.default_rng(seed)
    m, n_free, n_pos = 400, 3, 120
    a = rng.normal(size=(m, n_free + n_pos)) + 0.5 * rng.normal(size=(m, 1))  # correlated columns, as plays are
    truth = np.r_[rng.normal(size=n_free), np.where(rng.random(n_pos) < positive_share, rng.random(n_pos), 0.0)]
    x = a @ truth + 0.05 * rng.normal(size=m)
    w = nnls_gram(a.T @ a, a.T @ x, n_free)
    reference = _lawson_hanson(a, x, n_free)
    np.testing.assert_allclose(w, reference, atol=1e-9 * np.abs(reference).max())
    assert np.all(w[n_free:] >= 0)
    gradient = a.T @ x - a.T @ a @ w
    assert np.all(gradient[n_free:][w[n_free:] == 0] <= 1e-9 * np.abs(a.T @ x).max())  # no zero weight wants up


def test_a_matrix_that_is_not_positive_definite_falls_back():
    a = np.ones((10, 3))  # three equal columns: the Gram matrix is singular
    assert nnls_gram(a.T @ a, a.T @ np.arange(10.0), 0) is None
