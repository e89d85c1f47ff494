"""Symmetric Prandtl–Ishlinskii inverse model, SPI (paper eq. 1, 2 and 5)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fitting import check_fit_inputs, operator_widths, solve_weights
from .operators import osp, osp_weighted

__all__ = ["SPI"]


@dataclass(frozen=True, eq=False)
class SPI:
    """Inverse SPI model: desired displacement (m) → drive voltage (V).

    ``v(i) = Σ_j ω(j)·H(i, j)`` (eq. 1) with OSP operators H of widths r (eq. 2, 5) on the
    displacement, one weight vector for both branches — so it cannot describe a loop whose rising
    and falling branches differ other than by central symmetry.

    Attributes
    ----------
    widths : ndarray (N,)
        Operator widths r, metres (eq. 5).
    weights : ndarray (N,)
        Slopes ω, V/m; ``weights[0]`` (r = 0) is the linear gain and is bounded ≥ 0 in the fit.
    offset : float
        Displacement subtracted before the operators, metres: ``min(d)`` of the identification
        data, so bipolar records work with the same operator bank (0 for the paper's data).
    h0 : float
        Operator state before the first sample (eq. 4), metres, relative to ``offset``.
    bias : float
        Voltage at the shifted origin, V. Fitted only when ``offset != 0`` (bipolar records): the
        paper's eq. (1) has no constant because its input starts at the de-energised point
        (0 m, 0 V); once the displacement is shifted by ``offset`` that anchor is gone, and without
        a fitted constant the model is forced through 0 V at ``min(d)``. 0 for the paper's data.
    """

    widths: np.ndarray
    weights: np.ndarray
    offset: float = 0.0
    h0: float = 0.0
    bias: float = 0.0

    name = "spi"

    @classmethod
    def fit(cls, displacement, voltage, n_operators: int = 10, spacing: str = "eq5", h0: float = 0.0) -> "SPI":
        """Identify ω by linear least squares (eq. 6) on one record (M samples)."""
        d, v = check_fit_inputs(displacement, voltage, n_operators)
        offset = float(min(d.min(), 0.0))
        widths = operator_widths(np.ptp(d), n_operators, spacing)
        design = osp(d - offset, widths, h0)
        if offset != 0.0:  # bipolar record: the shifted origin is not at 0 V, fit the constant too
            design = np.hstack([design, np.ones((d.size, 1))])
        w = solve_weights(design, v, positive_columns=[0])
        return cls(widths, w[:n_operators], offset, h0, float(w[n_operators]) if offset != 0.0 else 0.0)

    def predict(self, displacement) -> np.ndarray:
        """Feedforward voltage (V) for a displacement trajectory (m), from the eq. (4) state."""
        d = np.asarray(displacement, dtype=np.float64)
        return osp_weighted(d - self.offset, self.widths, self.weights, self.h0) + self.bias

    def params(self) -> dict:
        """JSON-ready parameters (SI units)."""
        return {"widths_m": self.widths.tolist(), "weights_V_per_m": self.weights.tolist(),
                "offset_m": self.offset, "h0_m": self.h0, "bias_V": self.bias}
