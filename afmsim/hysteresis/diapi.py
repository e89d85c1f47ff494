"""Direct inverse asymmetric Prandtl–Ishlinskii model, DIAPI (paper eq. 3–7)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fitting import branch_signs, check_fit_inputs, operator_widths, solve_weights
from .operators import osp, osp_weighted

__all__ = ["DIAPI"]


@dataclass(frozen=True, eq=False)
class DIAPI:
    """Inverse DIAPI model: desired displacement (m) → drive voltage (V).

    ``v_a(i) = m·[ω_af ω_ab]ᵀ·H(i)`` (eq. 3): the OSP operator outputs H (eq. 2, widths of
    eq. 5, initial state of eq. 4) are weighted by ``weights_trace`` (ω_af) while the displacement
    rises and by ``weights_retrace`` (ω_ab) while it falls (branch = sign of the increment; a zero
    increment keeps the last branch). Both weight vectors come from one least-squares fit (eq. 6).

    Not modelled: the voltage jump ``(ω_af − ω_ab)·H`` at every reversal that the branch switch
    implies, rate dependence and creep.

    Attributes
    ----------
    widths : ndarray (N,)
        Operator widths r, metres.
    weights_trace, weights_retrace : ndarray (N,)
        ω_af and ω_ab, V/m; the r = 0 entries (linear gains) are bounded ≥ 0.
    offset : float
        Displacement subtracted before the operators (min of the identification data or 0), m.
    h0 : float
        Operator state before the first sample (eq. 4), metres relative to ``offset``.
    bias : float
        Voltage at the shifted origin, V; fitted only when ``offset != 0`` (bipolar records,
        see :class:`~afmsim.hysteresis.spi.SPI`), else 0 as in eq. (3).
    """

    widths: np.ndarray
    weights_trace: np.ndarray
    weights_retrace: np.ndarray
    offset: float = 0.0
    h0: float = 0.0
    bias: float = 0.0

    name = "diapi"

    @classmethod
    def fit(cls, displacement, voltage, n_operators: int = 10, spacing: str = "eq5", h0: float = 0.0) -> "DIAPI":
        """Identify ω_af and ω_ab by linear least squares (eq. 6) on one record."""
        d, v = check_fit_inputs(displacement, voltage, 2 * n_operators)
        offset = float(min(d.min(), 0.0))
        widths = operator_widths(np.ptp(d), n_operators, spacing)
        H = osp(d - offset, widths, h0)
        trace = (branch_signs(d) > 0)[:, None]
        design = np.hstack([H * trace, H * ~trace])
        if offset != 0.0:  # bipolar record: the shifted origin is not at 0 V, fit the constant too
            design = np.hstack([design, np.ones((d.size, 1))])
        w = solve_weights(design, v, positive_columns=[0, n_operators])
        bias = float(w[2 * n_operators]) if offset != 0.0 else 0.0
        return cls(widths, w[:n_operators], w[n_operators:2 * n_operators], offset, h0, bias)

    def predict(self, displacement) -> np.ndarray:
        """Feedforward voltage (V) for a displacement trajectory (m), from the eq. (4) state."""
        d = np.asarray(displacement, dtype=np.float64)
        weights = np.stack([self.weights_trace, self.weights_retrace])
        return osp_weighted(d - self.offset, self.widths, weights, self.h0) + self.bias

    @property
    def asymmetry(self) -> np.ndarray:
        """e_ω = (ω_af − ω_ab)/ω_ab per operator (eq. 7), as a fraction."""
        return (self.weights_trace - self.weights_retrace) / self.weights_retrace

    def params(self) -> dict:
        """JSON-ready parameters (SI units)."""
        return {"widths_m": self.widths.tolist(), "weights_trace_V_per_m": self.weights_trace.tolist(),
                "weights_retrace_V_per_m": self.weights_retrace.tolist(), "e_omega": self.asymmetry.tolist(),
                "offset_m": self.offset, "h0_m": self.h0, "bias_V": self.bias}
