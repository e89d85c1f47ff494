"""The loop fits' shortcuts give the fits they stand for: the training rows prepared once and a block
appended (:class:`afmsim.diagnosis.loops.model.TrainingRows`), and the Bouc–Wen shape search cut at the
last training sample (:func:`afmsim.diagnosis.loops.bouc_wen.fit_bouc_wen_shape`)."""

import numpy as np

from afmsim.diagnosis.loops.bouc_wen import BoucWenShape, backbone_columns, bouc_wen_state, fit_bouc_wen_shape
from afmsim.diagnosis.loops.model import TrainingRows, solve_training_rows, solve_weights


def _problem(rng, n=600, n_free=3, n_pos=25, n_new=4):
    free = np.column_stack([np.ones(n), rng.normal(size=(n, n_free - 1))])
    pos = np.abs(rng.normal(size=(n, n_pos))) * rng.uniform(0.1, 10.0, n_pos)
    pos[:, 5] = 0.0  # a column that never moves: held at zero
    new = rng.normal(size=(n, n_new)) * 1e-3
    w = np.r_[rng.normal(size=n_free), np.abs(rng.normal(size=n_pos)), np.abs(rng.normal(size=n_new))]
    x = np.hstack([free, pos, new]) @ w + 0.05 * rng.normal(size=n)
    mask = np.zeros(n, dtype=bool)
    mask[: int(0.6 * n)] = True
    mask[rng.choice(n, 40, replace=False)] = True
    return free, pos, new, x, mask


def test_appended_rows_give_the_gram_matrix_and_the_weights_of_the_joined_columns():
    rng = np.random.default_rng(7)
    free, pos, new, x, mask = _problem(rng)
    joined = TrainingRows.of((free, pos, new), mask)
    appended = TrainingRows.of((free, pos), mask).appended((new,), mask)
    np.testing.assert_allclose(appended.scale, joined.scale, rtol=1e-12)
    np.testing.assert_allclose(appended.gram, joined.gram, rtol=1e-10, atol=1e-10 * np.abs(joined.gram).max())
    assert np.array_equal(appended.moves, joined.moves) and not appended.moves[free.shape[1] + 5]
    np.testing.assert_allclose(appended.products(x[mask]), joined.products(x[mask]), rtol=1e-10)
    w = solve_training_rows(appended, free.shape[1], x[mask])
    w_free, w_pos = solve_weights(free, np.hstack([pos, new]), x, mask)
    np.testing.assert_allclose(w, np.r_[w_free, w_pos], rtol=1e-7, atol=1e-9 * np.abs(w).max())
    assert np.all(w[free.shape[1]:] >= 0) and w[free.shape[1] + 5] == 0.0


def test_the_effective_parameter_count_comes_back_with_the_weights():
    rng = np.random.default_rng(8)
    free, pos, _, x, mask = _problem(rng)
    w_free, w_pos, df = solve_weights(free, pos, x, mask, with_df=True)
    w, df_rows = solve_training_rows(TrainingRows.of((free, pos), mask), free.shape[1], x[mask], with_df=True)
    np.testing.assert_allclose(w, np.r_[w_free, w_pos], rtol=1e-12)
    # the free columns and the positive weights: at most the column count, at least the free ones
    assert df == df_rows and free.shape[1] <= df <= free.shape[1] + int(np.sum(w_pos > 0)) + 1e-9


def test_the_shape_search_never_reads_the_samples_after_the_last_training_one():
    rng = np.random.default_rng(9)
    n, block = 1500, 2
    u = np.clip(0.5 + 0.45 * np.sin(np.linspace(0, 9 * np.pi, n * block)) + 0.01 * rng.normal(size=n * block), 0, 1)
    h = bouc_wen_state(u, BoucWenShape(beta=6.0, gamma=1.5, n=1.3), block)
    um = u.reshape(n, block).mean(axis=1)
    free = np.column_stack([np.ones(n), um - 0.5])
    x = 1e-6 * (0.8 * um + 0.3 * h) + 2e-9 * rng.normal(size=n)
    mask = np.zeros(n, dtype=bool)
    mask[: int(0.6 * n)] = True
    shape, error = fit_bouc_wen_shape(u, block, free, x, mask, max_evaluations=60)
    # whatever the held-out samples hold, the same search and the same fit, to the last bit
    last = int(np.flatnonzero(mask)[-1]) + 1
    u2, x2, free2 = u.copy(), x.copy(), free.copy()
    u2[last * block:] = rng.uniform(size=u2.size - last * block)
    x2[last:] = 1.0
    free2[last:, 1] = -3.0
    shape2, error2 = fit_bouc_wen_shape(u2, block, free2, x2, mask, max_evaluations=60)
    assert shape2 == shape and error2 == error
    # and every training sample, the last one included, is in the fit it reports
    a = np.column_stack([free, backbone_columns(u, block), bouc_wen_state(u, shape, block)])[mask]
    w = np.linalg.lstsq(a, x[mask], rcond=None)[0]
    assert np.isclose(np.sqrt(np.mean((a @ w - x[mask]) ** 2)), error, rtol=1e-9, atol=0.0)
    assert error < 0.2 * np.std(x[mask])  # a fit, not a mean
