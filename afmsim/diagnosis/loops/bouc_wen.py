"""The Duhem hysteresis family (Bouc–Wen and Dahl laws) as a baseline alternative to the relay grid
(issue 11, point 3).

A Preisach grid has return-point memory: the branch after a reversal is set by the stored
reversal points. Duhem-class stages have none — the slope depends on the direction and on the
state only — and no relay density fits them (development nulls from :func:`.null_plants.bouc_wen`:
training RMS up to 38× the noise on any grid). This module fits the Bouc–Wen law (Bouc 1967; Wen,
J. Eng. Mech. 102 (1976) 249; for piezo stages Low & Guo, J. MEMS 4 (1995) 230) on the voltage
normalised to the training range, u ∈ [0, 1]:

    dh/du = A(u) − (β·sign(du·h) + γ)·|h|^n,   h = 0 at the record's first sample,
    A(u) = a_low·(1 − u) + a_high·u,            a_low² + a_high² = 2,
    x = b0 + b1·u' + b2·u'² + b3·u'³ + c·h     (u' the centred normalised voltage)

β > |γ| ≥ 0 keeps h bounded; n ∈ (1, 3). The drive term A is the classic law's constant 1 where
a_low = a_high = 1; letting it change linearly along the voltage (its scale is c's, so one angle
sets it) takes in the Duhem stages whose anhysteretic curve and reversal slope bend differently
— the Coleman–Hodgdon model ``dx = α|dv|(f(v) − x) + g(v)dv`` is this law with n = 1, γ = 0 and
A ∝ f′ − g (:func:`.null_plants.coleman_hodgdon`: with a constant A no family fitted such stages,
up to 135× the noise held out on development records). The output weights are linear and solved
by least squares for each shape (β, γ, n, A) — variable projection — and the shape minimises the
training error: the classic law from a coarse grid by Nelder–Mead, then all four from its
optimum and, where it fits better still, from the law's linear case (:func:`_linear_duhem_start`).
A decimated record's h is integrated on the full-rate voltage and block-averaged, as the relay
features are.

The family holds a second law, the Dahl law (Dahl, AIAA J. 14 (1976) 1675; for piezo stacks and
friction alike), ``dh/du = A(u)·|z|^α·sign(z)``, ``z = 1 − sign(du)·β·h``: a branch approaches
saturation as a power α of the distance left. At α = 1 it is the Bouc–Wen law with n = 1, γ = 0; at
any other α no Bouc–Wen law follows it, and on Dahl stages (α 0.5–2, :func:`.null_plants.dahl`,
outside the open-world suite's draw) the Bouc–Wen law alone left 3.2–12× the noise held out
(docs/diagnosis.md, "Families outside the suite"). Its shape (β, α, the drive term's angle) is
searched by Nelder–Mead from the best of :data:`DAHL_START_GRID`; of the two laws the one with the
smaller training error is kept (:func:`fit_bouc_wen_shape`; ``shape.law`` says which). An effect's
joint refit (:func:`.model.fit_model`) searches both laws again: the baseline's law is chosen with
the effect still in the record, and a 1 %/decade creep on a Bouc–Wen stage (spent open-world seed
47002, case 4) took the Dahl law there; refitted within it the creep left 5.3× the noise, with both
laws 1.4× (as before the Dahl law).

:meth:`afmsim.diagnosis.loops.model.Design.choose_family` takes this family instead of the grid
when its generalised cross-validation score on the training part is the smaller (df: its columns
plus the four shape parameters: β, γ, n and the drive term's angle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.optimize import minimize

from .record import block_means

__all__ = ["BoucWenShape", "bouc_wen_state", "bouc_wen_columns", "fit_bouc_wen_shape", "backbone_columns"]

#: Integration: the linearised trapezoidal rule (second order, and stable for any β > |γ| and n:
#: the state's own decay is taken half implicitly, so the step's divisor is ≥ 1), at least
#: :data:`MIN_SUBSTEPS` substeps per sample and one per :data:`MAX_STEP` of the normalised voltage (a
#: voltage step), at most :data:`MAX_SUBSTEPS`. On Bouc–Wen plants integrated by 8 explicit Euler
#: substeps per sample, backward Euler at 4 substeps left 1.4–1.8× the noise; this rule 1.0–1.05×.
MIN_SUBSTEPS = 4
MAX_STEP = 0.01
MAX_SUBSTEPS = 64
#: Starting grid of the shape search (the classic law, A ≡ 1): log β, atanh(γ/β) and the logit of (n − 1)/2.
START_GRID = tuple((np.log(b), g, c) for b in (1.0, 3.0, 10.0, 30.0) for g in (-0.5, 0.0, 0.5) for c in (-1.0, 1.0))
MAX_EVALUATIONS = 400
#: Second stage: Nelder–Mead from the classic law's optimum with the drive term's angle freed
#: (:meth:`BoucWenShape._drive_ends`), its first simplex :data:`REFINE_STEPS` wide; at most this many
#: evaluations (0: the classic law only). Searching all four from a grid of starts instead (angle
#: ±0.4) lost the classic optimum on Bouc–Wen records: a 3.2× worse training fit on one (spent
#: open-world seed 27002 case 2), 1.0× → 10× the noise held out.
DRIVE_TERM_EVALUATIONS = 400
REFINE_STEPS = (0.25, 0.25, 0.5, 0.5)
#: The Duhem laws the family fits (:func:`fit_bouc_wen_shape` keeps the one that fits the training part
#: better): the Bouc–Wen law, and the Dahl law (Dahl, AIAA J. 14 (1976) 1675),
#: ``dh/du = A(u)·|z|^α·sign(z)``, ``z = 1 − sign(du)·β·h`` — an approach to saturation that is a
#: power α of the distance left, which no Bouc–Wen law has unless α = 1 (then it is the Bouc–Wen law
#: with n = 1, γ = 0).
LAWS = ("bouc_wen", "dahl")
#: Range of the Dahl law's exponent α, and the starting grid of its search: log β, log α.
DAHL_ALPHA_RANGE = (0.2, 5.0)
DAHL_START_GRID = tuple((np.log(b), np.log(a)) for b in (2.0, 6.0, 20.0, 60.0) for a in (0.5, 1.0, 2.0))
#: β of the linear case's scan (:func:`_linear_duhem_start`), on the normalised voltage.
LINEAR_BETAS = tuple(np.geomspace(0.5, 100.0, 12))


@dataclass(frozen=True)
class BoucWenShape:
    """Shape of a Duhem law on the normalised voltage, drive term A(u) from ``a_low`` at u = 0 to
    ``a_high`` at u = 1 (both 1: a constant one). ``law="bouc_wen"``: β > |γ|, exponent n ∈ (1, 3);
    ``law="dahl"`` (:data:`LAWS`): β > 0 and the approach exponent ``alpha`` (γ and n unused)."""

    beta: float
    gamma: float
    n: float
    a_low: float = 1.0
    a_high: float = 1.0
    law: str = "bouc_wen"
    alpha: float = 1.0

    @classmethod
    def from_theta(cls, theta) -> "BoucWenShape":
        """Shape from the search's unconstrained parameters: log β, atanh(γ/β), logit((n − 1)/2)
        and the drive term's angle (:meth:`_drive_ends`; left out: the classic law, A ≡ 1)."""
        beta = float(np.exp(np.clip(theta[0], -5.0, 8.0)))
        return cls(beta=beta, gamma=float(np.tanh(theta[1]) * beta), n=float(1.0 + 2.0 / (1.0 + np.exp(-np.clip(theta[2], -30.0, 30.0)))),
                   **(cls._drive_ends(theta[3]) if len(theta) > 3 else {}))

    @classmethod
    def dahl_from_theta(cls, theta) -> "BoucWenShape":
        """Dahl law from the search's unconstrained parameters: log β, log α (α within
        :data:`DAHL_ALPHA_RANGE`) and the drive term's angle (:meth:`_drive_ends`; left out: A ≡ 1)."""
        lo, hi = np.log(DAHL_ALPHA_RANGE)
        return cls(beta=float(np.exp(np.clip(theta[0], -5.0, 8.0))), gamma=0.0, n=1.0, law="dahl",
                   alpha=float(np.exp(np.clip(theta[1], lo, hi))),
                   **(cls._drive_ends(theta[2]) if len(theta) > 2 else {}))

    @staticmethod
    def _drive_ends(angle) -> dict:
        """The drive term's ends on the circle a_low² + a_high² = 2 at φ = π/4 + (π/2)·tanh(angle) ∈
        (−π/4, 3π/4): every direction but its negative (h → −h flips A's sign, and c takes it)."""
        phi = 0.25 * np.pi + 0.5 * np.pi * np.tanh(angle)
        return {"a_low": float(np.sqrt(2.0) * np.cos(phi)), "a_high": float(np.sqrt(2.0) * np.sin(phi))}

    def as_dict(self) -> dict:
        out = {"law": self.law, "beta": self.beta, "a_low": self.a_low, "a_high": self.a_high}
        return {**out, "alpha": self.alpha} if self.law == "dahl" else {**out, "gamma": self.gamma, "exponent": self.n}


@njit(cache=True, nogil=True)
def _state(u, dahl, beta, gamma, n, alpha, a_low, a_high, block):  # pragma: no cover - compiled
    m = u.size // block
    out = np.zeros(m)
    h = 0.0
    for t in range(m * block):
        if t > 0:
            step = u[t] - u[t - 1]
            k = min(max(MIN_SUBSTEPS, int(np.ceil(abs(step) / MAX_STEP))), MAX_SUBSTEPS)
            du = step / k
            for j in range(k):
                here = u[t - 1] + (j + 0.5) * du
                drive = a_low + (a_high - a_low) * here
                if dahl:  # dh/du = A·|z|^α·sign(z), z = 1 − sign(du)·β·h
                    s = 1.0 if du > 0 else -1.0
                    z = 1.0 - s * beta * h
                    magnitude = max(abs(z), 1e-12)
                    change = du * drive * magnitude**alpha * np.sign(z)
                    jacobian = -abs(du * drive) * beta * alpha * magnitude ** (alpha - 1.0)
                else:  # dh/du = A − (β·sign(du·h) + γ)·|h|^n
                    rate = beta * np.sign(du * h) + gamma
                    magnitude = abs(h)
                    change = du * (drive - rate * magnitude**n)
                    jacobian = -du * rate * n * magnitude ** (n - 1.0) * np.sign(h)
                h += change / (1.0 - 0.5 * jacobian)
        out[t // block] += h / block
    return out


def bouc_wen_state(u, shape: BoucWenShape, block: int = 1) -> np.ndarray:
    """Hysteretic state h of the law on the normalised voltage ``u`` (full rate), averaged over
    consecutive blocks of ``block`` samples."""
    return _state(np.ascontiguousarray(u, dtype=np.float64), shape.law == "dahl", shape.beta, shape.gamma, shape.n,
                  shape.alpha, shape.a_low, shape.a_high, int(block))


def backbone_columns(u, block: int = 1) -> np.ndarray:
    """The nonlinear backbone terms u'², u'³ (u' = u − ½, ``u`` the normalised full-rate voltage),
    averaged over consecutive blocks of ``block`` samples as the record's x was. Squaring the
    block-mean voltage instead misses every block that holds a voltage step: on a Coleman–Hodgdon
    stage with a curved anhysteretic curve under 7 V steps, decimated 2× (development record
    902/coleman_hodgdon/3 of ``benchmarks/bench_other_families.py``), no family fitted within 17×
    the noise held out (the grid taken); with the block means 0.98×, the Bouc–Wen family taken. On a
    Dahl stage so drawn (902/dahl/4) the Dahl law's own shape left 27× on the training part (1.0× at
    full rate); with the block means 1.2× held out."""
    uc = np.asarray(u, dtype=np.float64) - 0.5
    return block_means(np.column_stack([uc**2, uc**3]), block)


def bouc_wen_columns(u, shape: BoucWenShape, block: int) -> np.ndarray:
    """The law's hysteresis columns [u'², u'³, h] (the weights of the design's free [1, u'] come on
    top); ``u`` the normalised full-rate voltage."""
    return np.column_stack([backbone_columns(u, block), bouc_wen_state(u, shape, block)])


def fit_bouc_wen_shape(u, block: int, free: np.ndarray, x: np.ndarray, mask: np.ndarray, *, transform=None, extra: np.ndarray | None = None,
                       max_evaluations: int = MAX_EVALUATIONS, laws=LAWS) -> tuple[BoucWenShape, float]:
    """Shape minimising the RMS training error on ``mask`` of ``x ≈ [T(free, backbone, h), extra]·w``
    (w by least squares), over the Duhem ``laws`` (:data:`LAWS`; each searched, the better kept);
    returns ``(shape, rms error [m])``.

    ``transform`` T (default: none) maps the hysteresis columns to the columns an effect fit makes
    of them (linear filters: the lag and resonance found, the creep bank's relaxations of every
    column) and ``extra`` free columns come on top (drift, cross-coupling), so that the shape is
    fitted jointly with the effects instead of absorbing them."""
    extra = np.empty((x.size, 0)) if extra is None else extra
    # the law, its backbone and every transform are causal: the samples after the last training one
    # never enter the fit (the same fit, to the last bit, at the cost of the samples up to it)
    rows = int(np.flatnonzero(mask)[-1]) + 1
    u, free, x, mask, extra = u[:rows * block], free[:rows], x[:rows], mask[:rows], extra[:rows]
    head = np.hstack([free, backbone_columns(u, block)])  # the columns no shape changes
    target = x[mask]
    untransformed = _MaskedColumns(head, extra, mask) if transform is None else None

    def misfit(states) -> float:
        """Mean square training error with the state columns ``states`` (M, k) after ``head``."""
        if untransformed is not None:
            a = untransformed.with_states(states)
            if a is None:
                return float("inf")
        else:
            cols = transform(np.hstack([head, states]))
            if not np.all(np.isfinite(cols)):
                return float("inf")
            a = np.hstack([cols, extra])[mask]
        w, *_ = np.linalg.lstsq(a, target, rcond=None)
        return float(np.mean((a @ w - target) ** 2))

    found = []
    if "bouc_wen" in laws:
        found.append(_search_bouc_wen(u, block, head, x, mask, misfit, max_evaluations))
    if "dahl" in laws:
        found.append(_search_dahl(u, block, misfit, max_evaluations))
    shape, mse = min(found, key=lambda f: f[1])
    return shape, float(np.sqrt(mse))


def _search_bouc_wen(u, block, head, x, mask, misfit, max_evaluations) -> tuple[BoucWenShape, float]:
    """The Bouc–Wen law's shape and its mean square training error (``misfit`` of its state): the
    classic law (A ≡ 1) from :data:`START_GRID` by Nelder–Mead, then the drive term freed from its
    optimum and, where it fits better still, from the law's linear case (:func:`_linear_duhem_start`)."""
    def error(theta) -> float:
        return misfit(bouc_wen_state(u, BoucWenShape.from_theta(theta), block)[:, None])

    theta0 = np.array(min(START_GRID, key=error))
    options = {"maxfev": max_evaluations, "xatol": 1e-3, "fatol": 1e-6 * error(theta0)}
    best = minimize(error, theta0, method="Nelder-Mead", options=options)
    if DRIVE_TERM_EVALUATIONS > 0:  # a simplex keeps its best vertex: never worse than the classic law
        starts = [np.r_[best.x, 0.0]]
        linear = _linear_duhem_start(u, block, head, x, mask, misfit)
        if error(linear) < best.fun:  # refined only where it already beats the classic law (it rarely does on
            starts.append(linear)     # a Bouc–Wen stage: half the search's time saved there)
        for start in starts:
            simplex = np.vstack([start, start + np.diag(REFINE_STEPS)])
            refined = minimize(error, start, method="Nelder-Mead",
                               options={**options, "maxfev": DRIVE_TERM_EVALUATIONS, "initial_simplex": simplex})
            best = refined if refined.fun < best.fun else best
    return BoucWenShape.from_theta(best.x), float(best.fun)


def _search_dahl(u, block, misfit, max_evaluations) -> tuple[BoucWenShape, float]:
    """The Dahl law's shape and its mean square training error: the best start of
    :data:`DAHL_START_GRID` (A ≡ 1), then β, α and the drive term's angle by Nelder–Mead from it."""
    def error(theta) -> float:
        return misfit(bouc_wen_state(u, BoucWenShape.dahl_from_theta(theta), block)[:, None])

    start = np.r_[min(DAHL_START_GRID, key=error), 0.0]
    simplex = np.vstack([start, start + np.diag((0.5, 0.5, 0.5))])
    best = minimize(error, start, method="Nelder-Mead",
                    options={"maxfev": max_evaluations, "xatol": 1e-3, "fatol": 1e-6 * error(start),
                             "initial_simplex": simplex})
    return BoucWenShape.dahl_from_theta(best.x), float(best.fun)


class _MaskedColumns:
    """The shape search's least-squares matrix on the training rows, ``[head, states, extra][mask]``,
    with ``head`` and ``extra`` copied in once and only the state columns written per evaluation (the
    same matrix, so the same fit, as stacking it anew: a few hundred evaluations per record)."""

    def __init__(self, head: np.ndarray, extra: np.ndarray, mask: np.ndarray):
        self.head, self.extra = head[mask], extra[mask]
        self.mask = mask
        self.finite = bool(np.all(np.isfinite(self.head)) and np.all(np.isfinite(self.extra)))
        self._buffers: dict[int, np.ndarray] = {}

    def with_states(self, states: np.ndarray) -> np.ndarray | None:
        """The matrix with ``states`` (M, k) in place; None where a column is not finite."""
        if not (self.finite and np.all(np.isfinite(states))):
            return None
        k, nh = states.shape[1], self.head.shape[1]
        if k not in self._buffers:
            a = np.empty((self.head.shape[0], nh + k + self.extra.shape[1]))
            a[:, :nh], a[:, nh + k:] = self.head, self.extra
            self._buffers[k] = a
        a = self._buffers[k]
        a[:, nh:nh + k] = states[self.mask]
        return a


def _linear_duhem_start(u, block: int, head: np.ndarray, x: np.ndarray, mask: np.ndarray, misfit) -> np.ndarray:
    """Search start (θ of :meth:`BoucWenShape.from_theta`) from the law's linear case, n = 1 and
    γ = 0 (the Coleman–Hodgdon class): there dh/du = A(u) − β·sign(du)·h is linear in h, so the state
    of A = a_low·(1 − u) + a_high·u is a_low·h₀ + a_high·h₁ (h₀, h₁ the states of the drive terms
    1 − u and u). For each β of :data:`LINEAR_BETAS` both enter one least-squares fit (``misfit`` of
    the state columns h₀, h₁ after ``head`` = [1, u', u'², u'³]); the best β, and a_high/a_low from its weights (fitted without
    the effects' transform), give the start. n = 1 lies at the edge of the search's range: the start
    takes n = 1 + 2/(1 + e⁴) ≈ 1.04."""
    def states(beta):
        ends = ((1.0, 0.0), (0.0, 1.0))
        return np.column_stack([bouc_wen_state(u, BoucWenShape(beta=beta, gamma=0.0, n=1.0, a_low=lo, a_high=hi), block) for lo, hi in ends])

    scanned = {beta: states(beta) for beta in LINEAR_BETAS}
    beta = min(LINEAR_BETAS, key=lambda b: misfit(scanned[b]))
    a = np.hstack([head, scanned[beta]])
    *_, w_low, w_high = np.linalg.lstsq(a[mask], x[mask], rcond=None)[0]
    phi = np.arctan2(w_high, w_low)  # the direction of (a_low, a_high), up to the sign c takes
    phi = (phi + 0.25 * np.pi) % np.pi - 0.25 * np.pi  # into (−π/4, 3π/4)
    angle = np.arctanh(np.clip((phi - 0.25 * np.pi) / (0.5 * np.pi), -0.999, 0.999))
    return np.array([np.log(beta), 0.0, -4.0, angle])
