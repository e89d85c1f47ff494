"""Elementary rate-independent backlash operators (paper §2.1, Figure 4).

Two operators are provided, each as a compiled kernel (numba, cached on disk) and as a plain
numpy reference that the tests compare against:

* the **one-side-play (OSP)** operator of eq. (2),
  ``H(i, j) = max{d(i) − r(j), min[d(i), H(i−1, j)]}``, whose output stays in ``[d − r, d]``;
* the classic **play** operator of half-width ``r``,
  ``P(i, j) = max{d(i) − r(j), min[d(i) + r(j), P(i−1, j)]}``, output in ``[d − r, d + r]``.

Initial state (eq. 4). The paper prints ``H(0) = max{d(0) − r, min[d(0) + r, h0]}``, which is the
*play*-operator form; for the OSP operator it leaves the band ``[d − r, d]`` whenever
``d(0) < h0``. Both agree whenever ``d(0) ≥ h0`` (the paper's case: a de-energised actuator,
``h0 = 0``, positive input). afmsim therefore starts each operator by applying its own update
rule once to the stored state ``h0``: ``H(0) = max{d(0) − r, min[d(0), h0]}`` for OSP and
``P(0) = max{d(0) − r, min[d(0) + r, h0]}`` for play — eq. (4) exactly for play, and eq. (4)'s
meaning for OSP. Bipolar input needs no special treatment: the recursion never assumes d ≥ 0.

Performance: the compiled kernel loops over samples outside and operators inside, writing into a
preallocated ``(M, N)`` array; see ``benchmarks/bench_operators.py`` for measured figures. Where only
weighted sums of the operator outputs are needed (a model's prediction), :func:`osp_weighted` forms
them sample by sample and never stores the ``(M, N)`` array (8·N bytes per sample less traffic).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["osp", "osp_weighted", "play", "osp_reference", "play_reference"]


@njit(cache=True, nogil=True)
def _osp_kernel(d, widths, h0, out):  # pragma: no cover - compiled
    m = d.shape[0]
    n = widths.shape[0]
    for j in range(n):
        out[0, j] = max(d[0] - widths[j], min(d[0], h0[j]))
    for i in range(1, m):
        di = d[i]
        for j in range(n):
            out[i, j] = max(di - widths[j], min(di, out[i - 1, j]))


@njit(cache=True, nogil=True)
def _play_kernel(d, widths, h0, out):  # pragma: no cover - compiled
    m = d.shape[0]
    n = widths.shape[0]
    for j in range(n):
        out[0, j] = max(d[0] - widths[j], min(d[0] + widths[j], h0[j]))
    for i in range(1, m):
        di = d[i]
        for j in range(n):
            out[i, j] = max(di - widths[j], min(di + widths[j], out[i - 1, j]))


@njit(cache=True, nogil=True)
def _osp_weighted_kernel(d, widths, h0, w_rise, w_fall, out):  # pragma: no cover - compiled
    state = h0.copy()
    rising = True
    for i in range(d.shape[0]):
        di = d[i]
        if i > 0:
            if di == d[i - 1]:  # a repeated input leaves every operator and the branch as they are
                out[i] = out[i - 1]
                continue
            rising = di > d[i - 1]
        w = w_rise if rising else w_fall
        total = 0.0
        for j in range(widths.shape[0]):
            state[j] = max(di - widths[j], min(di, state[j]))
            total += w[j] * state[j]
        out[i] = total


def _prepare(d, widths, h0):
    d = np.ascontiguousarray(d, dtype=np.float64)
    widths = np.ascontiguousarray(widths, dtype=np.float64)
    if d.ndim != 1 or d.size == 0:
        raise ValueError(f"input must be a non-empty 1-D array, got shape {d.shape}")
    if widths.ndim != 1 or widths.size == 0:
        raise ValueError(f"widths must be a non-empty 1-D array, got shape {widths.shape}")
    if np.any(widths < 0) or not np.all(np.isfinite(widths)):
        raise ValueError("widths must be finite and >= 0")
    h0 = np.broadcast_to(np.asarray(h0, dtype=np.float64), widths.shape).copy()
    return d, widths, h0


def osp(d, widths, h0=0.0) -> np.ndarray:
    """One-side-play operator outputs, eq. (2), compiled.

    Parameters
    ----------
    d : array_like, shape (M,)
        Operator input sequence (for the paper's inverse models: displacement in metres).
    widths : array_like, shape (N,)
        Operator widths r(j), same unit as ``d``, each ≥ 0 (eq. 5 gives the usual choice).
    h0 : float or array_like of shape (N,)
        Stored operator state before the first sample (eq. 4); 0 for a de-energised actuator.

    Returns
    -------
    numpy.ndarray, shape (M, N)
        ``H[i, j]``; each column lies in ``[d − r(j), d]``.
    """
    d, widths, h0 = _prepare(d, widths, h0)
    out = np.empty((d.size, widths.size))
    _osp_kernel(d, widths, h0, out)
    return out


def osp_weighted(d, widths, weights, h0=0.0) -> np.ndarray:
    """Weighted sum of the OSP operator outputs, ``Σ_j w_j·H(i, j)`` (the sum of eq. 3), compiled.

    Parameters
    ----------
    d, widths, h0 : as for :func:`osp` (input and widths in one unit, e.g. metres).
    weights : array_like, shape (N,) or (2, N)
        One weight vector for every sample, or the trace weights (row 0, used while ``d`` rises)
        and the retrace weights (row 1, while it falls); the branch is the sign of the increment
        of ``d``, a zero increment keeps the last branch and the first sample is on the trace, as
        in :func:`afmsim.hysteresis.fitting.branch_signs`.

    Returns
    -------
    numpy.ndarray, shape (M,)
        The weighted sums (e.g. volts for weights in V/m), formed sample by sample without
        storing the ``(M, N)`` operator outputs.
    """
    d, widths, h0 = _prepare(d, widths, h0)
    weights = np.asarray(weights, dtype=np.float64)
    if weights.shape not in ((widths.size,), (2, widths.size)):
        raise ValueError(f"weights must have shape ({widths.size},) or (2, {widths.size}), got {weights.shape}")
    w_rise, w_fall = (np.ascontiguousarray(w) for w in np.broadcast_to(weights, (2, widths.size)))
    out = np.empty(d.size)
    _osp_weighted_kernel(d, widths, h0, w_rise, w_fall, out)
    return out


def play(d, widths, h0=0.0) -> np.ndarray:
    """Classic play (backlash) operator of half-width ``r``, compiled.

    Same shapes and units as :func:`osp`; each column lies in ``[d − r(j), d + r(j)]``.
    """
    d, widths, h0 = _prepare(d, widths, h0)
    out = np.empty((d.size, widths.size))
    _play_kernel(d, widths, h0, out)
    return out


def osp_reference(d, widths, h0=0.0) -> np.ndarray:
    """Pure-numpy OSP (eq. 2): a Python loop over samples, vectorised over operators.

    Kept as the readable specification that the compiled kernel is tested against, and as the
    "naive" baseline of the operator benchmark.
    """
    d, widths, h0 = _prepare(d, widths, h0)
    out = np.empty((d.size, widths.size))
    state = np.maximum(d[0] - widths, np.minimum(d[0], h0))
    out[0] = state
    for i in range(1, d.size):
        state = np.maximum(d[i] - widths, np.minimum(d[i], state))
        out[i] = state
    return out


def play_reference(d, widths, h0=0.0) -> np.ndarray:
    """Pure-numpy play operator, the reference for :func:`play`."""
    d, widths, h0 = _prepare(d, widths, h0)
    out = np.empty((d.size, widths.size))
    state = np.maximum(d[0] - widths, np.minimum(d[0] + widths, h0))
    out[0] = state
    for i in range(1, d.size):
        state = np.maximum(d[i] - widths, np.minimum(d[i] + widths, state))
        out[i] = state
    return out
