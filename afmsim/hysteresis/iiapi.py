"""Indirect inverse asymmetric PI model, IIAPI — the paper's three-step baseline (Fig. 3a, §3.2).

Step 1 fits a **forward** asymmetric PI model (voltage → displacement), step 2 makes its initial
loading curves monotone, step 3 inverts it analytically per branch. DIAPI (Fig. 3b) skips
steps 1–3 by fitting the inverse directly; this class exists to compare accuracy and
identification time with it.

PI inversion used here (Krejčí & Kuhnen). For OSP operators (eq. 2) the initial loading curve of
``y = Σ_j a_j H_{r_j}(x)`` (x rising from the state where every operator equals x) is
``Φ(s) = Σ_j a_j (s − r_j)⁺`` — piecewise linear with breakpoints r_j and cumulative slopes
``A_j = Σ_{i≤j} a_i``. Its inverse ``Ψ = Φ⁻¹`` is again such a curve, so the inverse model is again
an OSP-PI model, with

* widths      ``r̂_j = Φ(r_j) = Σ_{i<j} a_i (r_j − r_i)``,
* weights     ``â_1 = 1/A_1``,  ``â_j = 1/A_j − 1/A_{j−1}``  (j ≥ 2).

OSP vs play: an OSP operator of width r is a play operator of half-width r/2 shifted by −r/2, and
the play-form inversion formulas (Kuhnen 2003) use half-widths; both the shift and the factor 2
cancel when the inverse is written with OSP operators and anchored at the common reference
state, which is why the formulas above carry no 1/2 and the inverse needs only the constant
``d_ref`` below.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fitting import branch_signs, check_fit_inputs, operator_widths, solve_weights
from .operators import osp, osp_weighted

__all__ = ["IIAPI", "invert_pi", "monotone_weights"]

#: Clipping rule of step 2: every cumulative slope A_j of the forward loading curve is raised to
#: at least this fraction of the largest one, so Φ is strictly increasing and Ψ exists.
MIN_RELATIVE_SLOPE = 1e-3


def monotone_weights(weights, min_relative_slope: float = MIN_RELATIVE_SLOPE) -> tuple[np.ndarray, int]:
    """Clip a PI weight vector so its loading curve is strictly increasing.

    The cumulative slopes ``A_j = Σ_{i≤j} a_i`` are clipped to ``≥ min_relative_slope·max_k A_k``
    (and ``max_k A_k`` must be > 0), then differenced back into weights. Returns the clipped
    weights and the number of clipped slopes. Raises ``ValueError`` when no slope is positive
    (the fitted forward model does not increase at all).
    """
    a = np.asarray(weights, dtype=np.float64)
    A = np.cumsum(a)
    top = A.max()
    if not top > 0:
        raise ValueError("forward PI model has no positive loading-curve slope: cannot be inverted")
    floor = min_relative_slope * top
    clipped = int(np.count_nonzero(A < floor))
    A = np.maximum(A, floor)
    return np.diff(A, prepend=0.0), clipped


def invert_pi(widths, weights) -> tuple[np.ndarray, np.ndarray]:
    """Analytic inverse of an OSP-PI model (widths r ascending with r_1 = 0, weights a).

    Returns ``(r̂, â)`` per the module docstring. Requires every cumulative slope > 0.
    """
    r = np.asarray(widths, dtype=np.float64)
    a = np.asarray(weights, dtype=np.float64)
    if r.ndim != 1 or r.shape != a.shape or r[0] != 0 or np.any(np.diff(r) <= 0):
        raise ValueError("widths must be strictly increasing from 0 and match the weights")
    A = np.cumsum(a)
    if np.any(A <= 0):
        raise ValueError(f"cumulative slopes must be positive to invert, got {A.tolist()}")
    # r̂_j = Φ(r_j) = Σ_{i<j} a_i (r_j − r_i)
    r_hat = np.array([np.sum(a[:j] * (r[j] - r[:j])) for j in range(r.size)])
    inv = 1.0 / A
    a_hat = np.diff(inv, prepend=0.0)
    return r_hat, a_hat


@dataclass(frozen=True, eq=False)
class IIAPI:
    """Indirect inverse asymmetric PI model: displacement (m) → voltage (V), via a forward model.

    Forward model (step 1, fitted by eq. 6 on the displacement)::

        d(i) = b + Σ_j a^s_j · H_j(v(i) − v_off),   s = branch of the voltage increment

    with OSP operators H on the voltage (widths r_j in V, eq. 5, state h0 of eq. 4), trace weights
    a⁺ and retrace weights a⁻ (m/V; linear gains bounded ≥ 0), ``v_off = min(v)`` for a bipolar
    drive (else 0) and a bias b (m), always fitted: a sensor's zero need not sit at 0 V.

    Inverse (steps 2–3, per branch s)::

        v(i) = v_off + h0 + Σ_j â^s_j · Ĥ^s_j(d(i) − d_ref^s),    d_ref^s = b + h0·Σ_j a^s_j

    with OSP operators Ĥ^s of widths r̂^s (m) and weights â^s (V/m) from :func:`invert_pi`, both
    banks run over the whole displacement history and the output taken from the bank of the
    current displacement branch (sign of the increment, zero keeps the branch). ``d_ref`` is the
    forward output in the reference state (every operator at h0, v − v_off = h0), so that the
    inverse banks started from the eq. (4) state with ĥ0 = 0 are on the same initial loading
    curve as the forward model.

    Exactness: for a symmetric forward model (a⁺ = a⁻) ``forward(predict(d)) = d`` exactly for
    any trajectory starting at or above the reference state. With a⁺ ≠ a⁻ each inverse bank sees
    the other branch's motion, so the composition is only approximate after a reversal — one
    reason the paper prefers the direct DIAPI fit.

    Step 2 rule (documented clipping): weights whose loading curve is not strictly increasing
    are replaced by :func:`monotone_weights` (cumulative slopes ≥ 0.1 % of the largest); the
    forward model keeps the *clipped* weights, so ``forward`` and ``predict`` stay exact
    inverses. ``n_clipped`` counts the clipped slopes of both branches.

    Not modelled: rate dependence and creep.
    """

    widths: np.ndarray
    forward_trace: np.ndarray
    forward_retrace: np.ndarray
    widths_inv_trace: np.ndarray
    weights_inv_trace: np.ndarray
    widths_inv_retrace: np.ndarray
    weights_inv_retrace: np.ndarray
    v_offset: float = 0.0
    bias: float = 0.0
    h0: float = 0.0
    n_clipped: int = 0

    name = "iiapi"

    @classmethod
    def fit(cls, displacement, voltage, n_operators: int = 10, spacing: str = "eq5", h0: float = 0.0) -> "IIAPI":
        """Steps 1–3: forward least-squares fit, monotone clipping, analytic per-branch inverse."""
        d, v = check_fit_inputs(displacement, voltage, 2 * n_operators)
        v_offset = float(min(v.min(), 0.0))
        widths = operator_widths(np.ptp(v), n_operators, spacing)
        if np.any(np.diff(widths) <= 0):
            raise ValueError("IIAPI needs at least one operator and distinct widths")
        H = osp(v - v_offset, widths, h0)
        trace = (branch_signs(v) > 0)[:, None]
        design = np.hstack([H * trace, H * ~trace, np.ones((d.size, 1))])
        # solve in units of the displacement's RMS: lsq_linear's tolerances are absolute-ish, and a
        # metre-sized target (~1e-6) would stop it early
        d_scale = float(np.sqrt(np.mean(d**2)))
        w = solve_weights(design, d / d_scale, positive_columns=[0, n_operators]) * d_scale
        bias = float(w[2 * n_operators])
        a_trace, clipped_trace = monotone_weights(w[:n_operators])
        a_retrace, clipped_retrace = monotone_weights(w[n_operators:2 * n_operators])
        r_t, w_t = invert_pi(widths, a_trace)
        r_r, w_r = invert_pi(widths, a_retrace)
        return cls(widths, a_trace, a_retrace, r_t, w_t, r_r, w_r, v_offset, bias, h0,
                   clipped_trace + clipped_retrace)

    def _d_ref(self, weights) -> float:
        return self.bias + self.h0 * float(np.sum(weights))

    def forward(self, voltage) -> np.ndarray:
        """Step-1 model: displacement (m) for a voltage trajectory (V), from the eq. (4) state."""
        v = np.asarray(voltage, dtype=np.float64)
        weights = np.vstack([self.forward_trace, self.forward_retrace])  # rising / falling voltage
        return osp_weighted(v - self.v_offset, self.widths, weights, self.h0) + self.bias

    def predict(self, displacement) -> np.ndarray:
        """Feedforward voltage (V) for a displacement trajectory (m), from the eq. (4) state."""
        d = np.asarray(displacement, dtype=np.float64)
        up = osp_weighted(d - self._d_ref(self.forward_trace), self.widths_inv_trace, self.weights_inv_trace)
        down = osp_weighted(d - self._d_ref(self.forward_retrace), self.widths_inv_retrace, self.weights_inv_retrace)
        return self.v_offset + self.h0 + np.where(branch_signs(d) > 0, up, down)

    @property
    def inverse_params(self) -> dict:
        """The analytic inverse (step 3): widths r̂ (m) and weights â (V/m) per branch."""
        return {"widths_trace_m": self.widths_inv_trace.tolist(), "weights_trace_V_per_m": self.weights_inv_trace.tolist(),
                "widths_retrace_m": self.widths_inv_retrace.tolist(),
                "weights_retrace_V_per_m": self.weights_inv_retrace.tolist(),
                "d_ref_trace_m": self._d_ref(self.forward_trace), "d_ref_retrace_m": self._d_ref(self.forward_retrace)}

    def params(self) -> dict:
        """JSON-ready parameters (SI units): forward model, clipping count and the inverse."""
        return {"widths_V": self.widths.tolist(), "forward_trace_m_per_V": self.forward_trace.tolist(),
                "forward_retrace_m_per_V": self.forward_retrace.tolist(), "v_offset_V": self.v_offset,
                "bias_m": self.bias, "h0_V": self.h0, "n_clipped": self.n_clipped, "inverse": self.inverse_params}
