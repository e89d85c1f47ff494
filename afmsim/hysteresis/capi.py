"""Continuous asymmetric PI inverse model, CAPI (afmsim's own; not one of the paper's models)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fitting import WIDTH_SPACINGS, check_fit_inputs, operator_widths, solve_weights
from .operators import osp

__all__ = ["CAPI", "capi_widths"]

#: Width spacings CAPI accepts: the paper's two plus ``"quadratic"``, r_i = ((i−1)/N)²·range.
CAPI_SPACINGS = WIDTH_SPACINGS + ("quadratic",)


def capi_widths(span: float, n_operators: int, spacing: str = "quadratic") -> np.ndarray:
    """Operator widths r (unit of ``span``); ``"quadratic"``: r_i = ((i−1)/N)²·span.

    The quadratic spacing puts more operators at small widths, where a measured loop curves most
    (just after each reversal); the widest operator is the same as eq. (5)'s, (N−1)²/N²·span.
    """
    if spacing != "quadratic":
        return operator_widths(span, n_operators, spacing)
    return operator_widths(span, n_operators, "eq5") ** 2 / float(span)


@dataclass(frozen=True, eq=False)
class CAPI:
    """Continuous asymmetric PI inverse model: desired displacement (m) → drive voltage (V).

    .. math::

        v(i) = c_0 + \\sum_{j=1}^{N} ω_j H_j(i)
               + \\sum_{j=2}^{N} \\sum_{k=2}^{K} γ_{jk}\\, r_j \\left(\\frac{p_j(i)}{r_j}\\right)^k
               + \\sum_{k=2}^{K_d} c_k\\, u(i)^k + \\sum_{j=2}^{N} β_j\\, p_j(i)\\, u(i)

    * ``H_j`` — OSP operators (eq. 2) on ``d − offset`` with widths ``r_j`` (m), started from the
      eq. (4) state ``h0``; ω_j (V/m) as in SPI, ω_1 (the linear gain) bounded ≥ 0.
    * ``p_j = (d − offset) − H_j ∈ [0, r_j]`` (m) — the lag of operator j. It grows from 0 to r_j
      on a rising branch and shrinks back on a falling one, so the memoryless powers
      ``r_j (p_j/r_j)^k`` (k ≥ 2, coefficients γ_jk in V/m) give the two branches *different
      shapes*, i.e. an asymmetric loop, while staying continuous functions of the operator state.
    * ``u = (d − d_mid)/(span/2)`` ∈ [−1, 1] on the identification range (dimensionless); the even
      and odd powers ``c_k u^k`` (V) bend the loop's centre line (memoryless asymmetry).
    * ``β_j p_j u`` (β_j in V/m) — a loop width that changes with the displacement level, as
      when the actuator's gain is level dependent (memoryless asymmetry acting on the memory).
    * ``c_0`` (V) — the voltage at the shifted origin (bipolar records).

    Why it beats DIAPI: DIAPI's asymmetry comes from switching the whole weight vector with the
    sign of the displacement increment, so its voltage jumps by ``(ω_af − ω_ab)·H`` at every
    reversal — and on a noisy measured record the sign chatters near each turn. CAPI has no
    branch switch: every term is a continuous function of the operator state, so the output is
    continuous at reversals and insensitive to increment-sign noise; the curvature terms and
    quadratic width spacing resolve the bend right after a reversal, where PI models err most.
    All parameters enter linearly: one bounded least-squares problem (scipy ``lsq_linear``).

    Not modelled: rate dependence and creep (like SPI/DIAPI). Limits: with ~3N parameters fitted
    on a major loop only, CAPI predicts *that* loop well but extrapolates to minor loops and to
    displacements outside the identification range worse than SPI/DIAPI (the powers of p and u
    are unconstrained there): identify it on the trajectories it will drive.

    Attributes
    ----------
    widths : ndarray (N,)
        Operator widths r, metres.
    weights : ndarray (N,)
        ω, V/m.
    curvature : ndarray (N−1, K−1)
        γ_jk for j = 2..N (the r = 0 operator has no lag) and k = 2..K, V/m.
    poly : ndarray (K_d + 1,)
        c_0, c_1 (always 0: the linear term is ω_1's), c_2 … c_Kd, V.
    offset : float
        Displacement subtracted before the operators, m (min of the identification data or 0).
    d_mid, half_span : float
        Centre and half-range of the identification displacement, m (define u).
    cross : ndarray (N−1,)
        β_j for j = 2..N, V/m.
    h0 : float
        Operator state before the first sample (eq. 4), m relative to ``offset``.
    """

    widths: np.ndarray
    weights: np.ndarray
    curvature: np.ndarray
    poly: np.ndarray
    offset: float
    d_mid: float
    half_span: float
    cross: np.ndarray
    h0: float = 0.0

    name = "capi"

    @staticmethod
    def _blocks(d, widths, offset, d_mid, half_span, h0, degree, poly_degree):
        """The design's column blocks, in the order of the weights: H, 1, the lag powers
        r·(lag/r)^k (k = 2…K), u^k (k = 2…K_d) and lag·u."""
        x = d - offset
        H = osp(x, widths, h0)
        lag = x[:, None] - H[:, 1:]
        r = widths[1:]
        u = (d - d_mid) / half_span
        yield H
        yield np.ones((d.size, 1))
        for k in range(2, degree + 1):
            yield r * (lag / r) ** k
        for k in range(2, poly_degree + 1):
            yield u[:, None] ** k
        yield lag * u[:, None]

    @classmethod
    def _design(cls, *args) -> np.ndarray:
        return np.hstack(list(cls._blocks(*args)))

    @classmethod
    def fit(cls, displacement, voltage, n_operators: int = 10, spacing: str = "quadratic", h0: float = 0.0,
            degree: int = 3, poly_degree: int = 3) -> "CAPI":
        """Identify ω, γ and c by one linear least-squares fit (eq. 6's error function).

        ``degree`` K ≥ 1 (1: no lag powers) and ``poly_degree`` K_d ≥ 1 (1: no powers of u) are
        the highest powers; ``spacing`` is ``"quadratic"`` (default), ``"eq5"`` or ``"table1"``.
        """
        if spacing not in CAPI_SPACINGS:
            raise ValueError(f"spacing must be one of {CAPI_SPACINGS}, got {spacing!r}")
        for label, value in (("degree", degree), ("poly_degree", poly_degree)):
            if not (isinstance(value, (int, np.integer)) and 1 <= value <= 8):
                raise ValueError(f"{label} must be an integer in [1, 8], got {value!r}")
        if not (isinstance(n_operators, (int, np.integer)) and 2 <= n_operators <= 200):
            raise ValueError(f"n_operators must be an integer in [2, 200] for CAPI, got {n_operators!r}")
        n_weights = n_operators + 1 + (n_operators - 1) * degree + (poly_degree - 1)
        d, v = check_fit_inputs(displacement, voltage, n_weights)
        offset = float(min(d.min(), 0.0))
        span = float(np.ptp(d))
        widths = capi_widths(span, n_operators, spacing)
        d_mid, half_span = float(d.min() + span / 2), span / 2
        design = cls._design(d, widths, offset, d_mid, half_span, h0, degree, poly_degree)
        w = solve_weights(design, v, positive_columns=[0])
        n = n_operators
        curvature = w[n + 1:n + 1 + (n - 1) * (degree - 1)].reshape(degree - 1, n - 1).T
        poly = np.concatenate([[w[n], 0.0], w[n + 1 + (n - 1) * (degree - 1):n + (n - 1) * (degree - 1) + poly_degree]])
        cross = w[n + 1 + (n - 1) * (degree - 1) + poly_degree - 1:]
        return cls(widths, w[:n], curvature, poly, offset, d_mid, half_span, cross, h0)

    @property
    def degree(self) -> int:
        return self.curvature.shape[1] + 1

    @property
    def poly_degree(self) -> int:
        return self.poly.size - 1

    def predict(self, displacement) -> np.ndarray:
        """Feedforward voltage (V) for a displacement trajectory (m), from the eq. (4) state.

        The fit's design matrix times the weights, block by block, so no (M, N·K) matrix is built
        for a long trajectory.
        """
        d = np.asarray(displacement, dtype=np.float64)
        w = np.concatenate([self.weights, [self.poly[0]], self.curvature.T.ravel(), self.poly[2:], self.cross])
        voltage, start = np.zeros(d.size), 0
        for block in self._blocks(d, self.widths, self.offset, self.d_mid, self.half_span, self.h0,
                                  self.degree, self.poly_degree):
            voltage += block @ w[start:start + block.shape[1]]
            start += block.shape[1]
        return voltage

    def params(self) -> dict:
        """JSON-ready parameters (SI units)."""
        return {"widths_m": self.widths.tolist(), "weights_V_per_m": self.weights.tolist(),
                "curvature_V_per_m": self.curvature.tolist(), "poly_V": self.poly.tolist(),
                "offset_m": self.offset, "d_mid_m": self.d_mid, "half_span_m": self.half_span, "h0_m": self.h0,
                "degree": self.degree, "poly_degree": self.poly_degree}
