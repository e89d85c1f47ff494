"""The Bouc–Wen hysteresis family as a baseline alternative to the relay grid (issue 11, point 3).

A Preisach grid has return-point memory: the branch after a reversal is set by the stored
reversal points. Duhem-class stages have none — the slope depends on the direction and on the
state only — and no relay density fits them (development nulls from :func:`.null_plants.bouc_wen`:
training RMS up to 38× the noise on any grid). This module fits the Bouc–Wen law (Bouc 1967; Wen,
J. Eng. Mech. 102 (1976) 249; for piezo stages Low & Guo, J. MEMS 4 (1995) 230) on the voltage
normalised to the training range, u ∈ [0, 1]:

    dh/du = 1 − (β·sign(du·h) + γ)·|h|^n,   h = 0 at the record's first sample,
    x = b0 + b1·u' + b2·u'² + b3·u'³ + c·h     (u' the centred normalised voltage)

β > |γ| ≥ 0 keeps h bounded (|h| ≤ (β − |γ|)^(−1/n)); n ∈ (1, 3). The output weights are linear
and solved by least squares for each shape (β, γ, n) — variable projection — and the shape
minimises the training error (a coarse grid, then Nelder–Mead). A decimated record's h is
integrated on the full-rate voltage and block-averaged, as the relay features are.

:meth:`afmsim.diagnosis.loops.model.Design.choose_family` takes this family instead of the grid
when its generalised cross-validation score on the training part is the smaller (df: its columns
plus the three shape parameters).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.optimize import minimize

__all__ = ["BoucWenShape", "bouc_wen_state", "bouc_wen_columns", "fit_bouc_wen_shape", "backbone_columns"]

#: Integration: the linearised trapezoidal rule (second order, and stable for any β > |γ| and n:
#: the state's own decay is taken half implicitly, so the step's divisor is ≥ 1), at least
#: :data:`MIN_SUBSTEPS` substeps per sample and one per :data:`MAX_STEP` of the normalised voltage (a
#: voltage step), at most :data:`MAX_SUBSTEPS`. On Bouc–Wen plants integrated by 8 explicit Euler
#: substeps per sample, backward Euler at 4 substeps left 1.4–1.8× the noise; this rule 1.0–1.05×.
MIN_SUBSTEPS = 4
MAX_STEP = 0.01
MAX_SUBSTEPS = 64
#: Starting grid of the shape search: log β, atanh(γ/β) and the logit of (n − 1)/2.
START_GRID = tuple((np.log(b), g, c) for b in (1.0, 3.0, 10.0, 30.0) for g in (-0.5, 0.0, 0.5) for c in (-1.0, 1.0))
MAX_EVALUATIONS = 400


@dataclass(frozen=True)
class BoucWenShape:
    """Shape of the Bouc–Wen law on the normalised voltage: β > |γ|, exponent n ∈ (1, 3)."""

    beta: float
    gamma: float
    n: float

    @classmethod
    def from_theta(cls, theta) -> "BoucWenShape":
        beta = float(np.exp(np.clip(theta[0], -5.0, 8.0)))
        return cls(beta=beta, gamma=float(np.tanh(theta[1]) * beta), n=float(1.0 + 2.0 / (1.0 + np.exp(-np.clip(theta[2], -30.0, 30.0)))))

    def as_dict(self) -> dict:
        return {"beta": self.beta, "gamma": self.gamma, "exponent": self.n}


@njit(cache=True, nogil=True)
def _state(u, beta, gamma, n, block):  # pragma: no cover - compiled
    m = u.size // block
    out = np.zeros(m)
    h = 0.0
    for t in range(m * block):
        if t > 0:
            step = u[t] - u[t - 1]
            k = min(max(MIN_SUBSTEPS, int(np.ceil(abs(step) / MAX_STEP))), MAX_SUBSTEPS)
            du = step / k
            for _ in range(k):
                rate = beta * np.sign(du * h) + gamma
                magnitude = abs(h)
                slope = du * (1.0 - rate * magnitude**n)
                jacobian = -du * rate * n * magnitude ** (n - 1.0) * np.sign(h)
                h += slope / (1.0 - 0.5 * jacobian)
        out[t // block] += h / block
    return out


def bouc_wen_state(u, shape: BoucWenShape, block: int = 1) -> np.ndarray:
    """Hysteretic state h of the law on the normalised voltage ``u`` (full rate), averaged over
    consecutive blocks of ``block`` samples."""
    return _state(np.ascontiguousarray(u, dtype=np.float64), shape.beta, shape.gamma, shape.n, int(block))


def backbone_columns(free: np.ndarray) -> np.ndarray:
    """The nonlinear backbone terms u'², u'³ from the design's free columns [1, u']."""
    u = free[:, 1]
    return np.column_stack([u**2, u**3])


def bouc_wen_columns(u, shape: BoucWenShape, block: int, free: np.ndarray) -> np.ndarray:
    """The law's hysteresis columns [u'², u'³, h] (the weights of the design's ``free`` [1, u'] come
    on top); ``u`` the normalised full-rate voltage."""
    return np.column_stack([backbone_columns(free), bouc_wen_state(u, shape, block)])


def fit_bouc_wen_shape(u, block: int, free: np.ndarray, x: np.ndarray, mask: np.ndarray, *, transform=None, extra: np.ndarray | None = None,
                       max_evaluations: int = MAX_EVALUATIONS) -> tuple[BoucWenShape, float]:
    """Shape minimising the RMS training error on ``mask`` of ``x ≈ [T(free, backbone, h), extra]·w``
    (w by least squares); returns ``(shape, rms error [m])``.

    ``transform`` T (default: none) maps the hysteresis columns to the columns an effect fit makes
    of them (linear filters: the lag and resonance found, the creep bank's relaxations of every
    column) and ``extra`` free columns come on top (drift, cross-coupling), so that the shape is
    fitted jointly with the effects instead of absorbing them."""
    extra = np.empty((x.size, 0)) if extra is None else extra

    def error(theta) -> float:
        cols = np.hstack([free, bouc_wen_columns(u, BoucWenShape.from_theta(theta), block, free)])
        if transform is not None:
            cols = transform(cols)
        if not np.all(np.isfinite(cols)):
            return float("inf")
        a = np.hstack([cols, extra])[mask]
        w, *_ = np.linalg.lstsq(a, x[mask], rcond=None)
        return float(np.mean((a @ w - x[mask]) ** 2))

    theta0 = np.array(min(START_GRID, key=error))
    best = minimize(error, theta0, method="Nelder-Mead",
                    options={"maxfev": max_evaluations, "xatol": 1e-3, "fatol": 1e-6 * error(theta0)})
    return BoucWenShape.from_theta(best.x), float(np.sqrt(best.fun))
