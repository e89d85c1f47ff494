"""Shared pieces of the least-squares identification (paper eq. 5 and 6).

Every model in :mod:`afmsim.hysteresis` is linear in its weights once the operator outputs are
computed, so identification is one bounded linear least-squares problem solved by
:func:`scipy.optimize.lsq_linear`; the only physical bound is a positive linear gain.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

__all__ = ["WIDTH_SPACINGS", "operator_widths", "check_fit_inputs", "branch_signs", "solve_weights"]

#: Width spacings (paper eq. 5 vs Table 1). ``"eq5"``: r_i = (i−1)/N·range (default: every
#: operator is active on the identification loop); ``"table1"``: r_i = (i−1)/(N−1)·range, as the
#: paper's Table 1 lists (0, 11.1, …, 99.9 µm) — its last operator spans the whole range and is
#: then almost idle, which is why Table 1's last weights are so poorly determined.
WIDTH_SPACINGS = ("eq5", "table1")

MIN_SAMPLES_PER_WEIGHT = 4


def operator_widths(span: float, n_operators: int, spacing: str = "eq5") -> np.ndarray:
    """Operator widths r of eq. (5), in the unit of ``span`` (= max(d) − min(d))."""
    if spacing not in WIDTH_SPACINGS:
        raise ValueError(f"spacing must be one of {WIDTH_SPACINGS}, got {spacing!r}")
    if not (isinstance(n_operators, (int, np.integer)) and 1 <= n_operators <= 200):
        raise ValueError(f"n_operators must be an integer in [1, 200], got {n_operators!r}")
    denominator = n_operators if spacing == "eq5" or n_operators == 1 else n_operators - 1
    return np.arange(n_operators) / denominator * float(span)


def check_fit_inputs(displacement, voltage, n_weights: int) -> tuple[np.ndarray, np.ndarray]:
    """Validate identification data; returns float64 copies.

    Raises ``ValueError`` with a message naming the problem for: non-1-D input, length
    mismatch, NaN/inf, a constant input, or fewer than ``4·n_weights`` samples.
    """
    d = np.asarray(displacement, dtype=np.float64)
    v = np.asarray(voltage, dtype=np.float64)
    if d.ndim != 1 or v.ndim != 1:
        raise ValueError(f"displacement and voltage must be 1-D arrays, got shapes {d.shape} and {v.shape}")
    if d.size != v.size:
        raise ValueError(f"displacement and voltage lengths differ: {d.size} vs {v.size}")
    for name, arr in (("displacement", d), ("voltage", v)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} contains NaN or inf ({np.count_nonzero(~np.isfinite(arr))} samples)")
    needed = MIN_SAMPLES_PER_WEIGHT * n_weights
    if d.size < needed:
        raise ValueError(f"too few samples to identify {n_weights} weights: got {d.size}, need at least {needed}")
    if np.ptp(d) == 0:
        raise ValueError("displacement is constant: a hysteresis loop needs a moving input")
    if np.ptp(v) == 0:
        raise ValueError("voltage is constant: a hysteresis loop needs a moving input")
    return d, v


def branch_signs(d: np.ndarray) -> np.ndarray:
    """Branch of each sample: +1 on the trace (rising d), −1 on the retrace (falling d).

    The branch is the sign of the increment d(i) − d(i−1); a zero increment keeps the previous
    branch, and the first sample (and any leading flat part) is on the trace, as for an
    actuator that starts from rest and extends first (paper §2.3, m = [1 0] / [0 1] of eq. 3).
    """
    d = np.asarray(d, dtype=np.float64)
    step = np.sign(np.diff(d, prepend=d[:1]))
    index = np.where(step != 0, np.arange(d.size), 0)
    np.maximum.accumulate(index, out=index)
    signs = step[index]
    signs[signs == 0] = 1.0
    return signs


def solve_weights(design: np.ndarray, target: np.ndarray, positive_columns=()) -> np.ndarray:
    """Minimise ‖design·w − target‖² (eq. 6) with ``w[k] ≥ 0`` for ``k in positive_columns``.

    Columns are scaled to unit RMS before solving so that metre-sized operator outputs and
    volt-sized targets are equally well conditioned; the returned weights are unscaled.
    """
    scale = np.sqrt(np.mean(design**2, axis=0))
    scale[scale == 0] = 1.0
    lower = np.full(design.shape[1], -np.inf)
    lower[list(positive_columns)] = 0.0
    result = lsq_linear(design / scale, target, bounds=(lower, np.inf), method="bvls", tol=1e-12)
    return result.x / scale
