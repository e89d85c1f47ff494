"""Which minor-loop law does a loop record support: Preisach (state-bound) or Duhem (direction-bound)?

Both laws are fitted on the training part of the record and scored on the held-out part (the same
split and the same creep treatment for both), and the law with the smaller held-out RMS gap is
named when the other's gap is at least :data:`DECISIVE_RATIO` times larger:

* **Preisach law** — ``x = b0 + b1·v + Σ μ_ij s_ij(v)``, smoothed relays on the training voltage
  range (:func:`afmsim.diagnosis.loops.model.relay_features`) plus relays whose down-threshold lies below
  it (:func:`latched_relays`), μ ≥ 0. After a reversal the branch is set
  by the stored reversal points: wiping-out, congruent minor loops.
* **Duhem law** (Coleman–Hodgdon form) — ``dx/dû = g(û) + σ·α(û)·(f(û) − x)`` with σ the sign of
  dû, û the voltage normalised to the training range, f and g piecewise-linear (hat functions on
  :data:`N_KNOTS` knots) and ``α(û) = a + p/û``. For fixed (a, p) the solution is linear in the
  coefficients of f and g and in the initial state, so each grid point (a, p) is a linear
  least-squares fit; (a, p) minimise the training error (a grid, then Nelder–Mead). The branch slope is
  set by the direction and the distance to f only: no memory of reversal points.

Creep (a log-spaced bank of relaxations, :func:`_creep_columns`) is fitted with either law, so a
creeping record does not favour one of them.

A record with fewer than :data:`MIN_INTERIOR_REVERSALS` reversals inside its voltage range (a
single-amplitude loop from 0 V, such as the paper's identification loop) cannot tell the laws
apart: from rest both close their loops at the ends. :func:`minor_loop_excitation` is the record
to take instead: docs/reference-results.md ("Which minor-loop law does your stage follow?") says why.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.optimize import minimize
from scipy.signal import lfilter, lfilter_zi

from afmsim.reproducible import single_blas_thread

from ..engine import rms
from .model import creep_taus, drive_polarity, lag_filter, relay_features, solve_weights

__all__ = ["minor_loop_law", "minor_loop_excitation", "interior_reversals", "LAWS", "DECISIVE_RATIO"]

LAWS = ("preisach", "duhem")
#: The other law's held-out RMS gap must be at least this many times the named law's.
DECISIVE_RATIO = 1.15
MIN_INTERIOR_REVERSALS = 4
N_KNOTS = 16
#: Relay-grid size of the Preisach law (the loop diagnosis baseline's grid before it became finer:
#: the law comparison was validated with it).
N_LEVELS = 16
#: Duhem relaxation grid: constant part a (per unit of the normalised input) and the 1/û part p.
RATE_GRID = (0.3, 1.0, 2.0, 4.0, 8.0, 16.0)
INVERSE_GRID = (0.0, 0.5, 1.5)


def minor_loop_excitation(amplitudes_V=(4.5, 3.5, 2.5, 1.5, 0.75), centre_V: float = 4.55, peak_V: float = 9.1,
                          frequency_hz: float = 1.0, sample_rate_hz: float = 1000.0, cycles: int = 2):
    """The record that tells the laws apart: ``(t, v)``, t in s, v in V.

    One major loop 0 → ``peak_V`` → ``centre_V``, then ``cycles`` triangle cycles about
    ``centre_V`` at each of ``amplitudes_V`` in *decreasing* order (a decaying excitation), then the
    same cycles in *increasing* order, then back to 0 V. Every cycle is swept at the speed of a
    ``frequency_hz`` triangle of the full amplitude ``peak_V`` (rate-independent regime). The
    decreasing half trains; the increasing half, held out, revisits the same voltages after a
    different history — where the stored reversal points (Preisach) and the direction alone (Duhem)
    predict different branches.
    """
    amplitudes = [float(a) for a in amplitudes_V]
    if not amplitudes or min(amplitudes) <= 0 or centre_V - max(amplitudes) < 0 or centre_V + max(amplitudes) > peak_V:
        raise ValueError("amplitudes_V must be > 0 and keep centre_V ± amplitude inside [0, peak_V]")
    points = [0.0, peak_V, centre_V]
    for a in amplitudes + amplitudes[::-1]:
        points += [centre_V - a, centre_V + a] * cycles + [centre_V]
    points.append(0.0)
    speed = 2.0 * peak_V * frequency_hz  # V/s
    v = [np.array([points[0]])]
    for a, b in zip(points[:-1], points[1:]):
        n = max(1, int(round(abs(b - a) / speed * sample_rate_hz)))
        v.append(np.linspace(a, b, n + 1)[1:])
    v = np.concatenate(v)
    return np.arange(v.size) / sample_rate_hz, v


def interior_reversals(v, margin: float = 0.03) -> int:
    """Reversals of the drive ``v`` more than ``margin`` of its range inside its extremes."""
    v = np.asarray(v, dtype=np.float64)
    dv = np.diff(v)
    moving = dv[dv != 0]
    turns = np.flatnonzero(np.sign(moving[1:]) != np.sign(moving[:-1]))
    values = np.cumsum(np.r_[v[0], moving])[turns + 1]
    lo, hi = v.min(), v.max()
    inside = (values > lo + margin * (hi - lo)) & (values < hi - margin * (hi - lo))
    return int(inside.sum())


@njit(cache=True, nogil=True)
def _duhem_columns(u, knots, rate, inverse, out):  # pragma: no cover - compiled
    """Responses of the Duhem law to each basis function (columns of ``out``).

    Columns 0..K−1: unit hat function k in f (g = 0); K..2K−1: in g (f = 0); 2K: the initial
    state (f = g = 0, x(0) = 1). Each step û0 → û1 is integrated exactly for α, f, g frozen at the
    step's midpoint: x ← x* + (x − x*)·exp(−α|Δû|), x* = f + σ·g/α.
    """
    k = knots.shape[0]
    h = knots[1] - knots[0]
    state = np.zeros(2 * k + 1)
    state[2 * k] = 1.0
    for c in range(2 * k + 1):
        out[0, c] = state[c]
    for t in range(1, u.shape[0]):
        du = u[t] - u[t - 1]
        if du != 0.0:
            sigma = 1.0 if du > 0 else -1.0
            mid = 0.5 * (u[t] + u[t - 1])
            alpha = rate + inverse / max(mid, 1e-3)
            decay = np.exp(-alpha * abs(du))
            for j in range(k):
                hat = max(0.0, 1.0 - abs(mid - knots[j]) / h)
                state[j] = hat + (state[j] - hat) * decay
                g_star = sigma * hat / alpha
                state[k + j] = g_star + (state[k + j] - g_star) * decay
            state[2 * k] *= decay
        for c in range(2 * k + 1):
            out[t, c] = state[c]


def latched_relays(v, v_lo: float, v_hi: float, n_levels: int = N_LEVELS) -> np.ndarray:
    """Relays whose down-threshold lies below the recorded range (M, n_levels): once switched on
    (smoothed over one cell, as :func:`~afmsim.diagnosis.loops.model.relay_features`) they stay on. The
    Preisach plane of a stage is not bounded by the record's voltages: a record that does not start
    de-energised, or a stage whose loops do not close at the lowest voltage, needs them."""
    u = (np.asarray(v, dtype=np.float64) - v_lo) / (v_hi - v_lo) * n_levels
    ramps = np.clip(u[:, None] - np.arange(n_levels)[None, :], 0.0, 1.0)
    return np.maximum.accumulate(ramps, axis=0)


def duhem_columns(v, v_lo: float, v_hi: float, rate: float, inverse: float) -> np.ndarray:
    """The Duhem law's design matrix (M, 2·N_KNOTS + 1) for drive ``v`` on the range [v_lo, v_hi]."""
    u = np.clip((np.asarray(v, dtype=np.float64) - v_lo) / (v_hi - v_lo), 0.0, 1.0)
    out = np.empty((u.size, 2 * N_KNOTS + 1))
    _duhem_columns(np.ascontiguousarray(u), np.linspace(0.0, 1.0, N_KNOTS), float(rate), float(inverse), out)
    return out


def _creep_columns(vn, taus, dt) -> np.ndarray:
    """Creep bank ``LP_τ(v) − v`` on the normalised drive (started in steady state).

    Creep acts on the displacement, which is the drive times the sensitivity up to the ~10 %
    hysteresis: relaxing the drive instead keeps both laws linear in their weights (one solve) at
    the price of a second-order error (hysteresis share × creep, < 0.5 % of the creep)."""
    cols = []
    for tau in taus:
        b, a = lag_filter(tau, dt)
        y, _ = lfilter(b, a, vn, zi=lfilter_zi(b, a) * vn[0])
        cols.append(y - vn)
    return np.column_stack(cols)


def _predict(free, positive, x, train):
    """The prediction over the whole record of the least-squares fit on ``train`` with the
    ``positive`` columns' weights ≥ 0 (the baseline's solver,
    :func:`afmsim.diagnosis.loops.model.solve_weights`)."""
    w_free, w_positive = solve_weights(free, positive, x, train)
    return free @ w_free + positive @ w_positive


def _fit_duhem(v, lo, hi, x, train, extra) -> tuple[np.ndarray, float, float]:
    """Duhem law: (prediction, a, p) minimising the training error; the weights by linear least
    squares for each (a, p), (a, p) by a grid then Nelder–Mead on (log a, p)."""
    none = np.empty((v.size, 0))

    def predict(rate, inverse):
        return _predict(np.hstack([duhem_columns(v, lo, hi, rate, inverse), extra]), none, x, train)

    def train_error(theta):
        return rms((predict(np.exp(theta[0]), abs(theta[1])) - x)[train])

    start = min(((np.log(a), p) for a in RATE_GRID for p in INVERSE_GRID), key=train_error)
    theta = minimize(train_error, np.array(start), method="Nelder-Mead",
                     options={"xatol": 1e-3, "fatol": 1e-4 * rms(x[train] - x[train].mean()), "maxiter": 200}).x
    rate, inverse = float(np.exp(theta[0])), float(abs(theta[1]))
    return predict(rate, inverse), rate, inverse



@single_blas_thread
def minor_loop_law(t, v, x, train, sigma: float) -> dict:
    """Fit both minor-loop laws on ``train`` (bool mask) and compare their held-out gaps.

    ``t`` (s), ``v`` (V), ``x`` (m) are the validated record's columns, ``sigma`` its noise floor
    (m). Held-out samples outside the training voltage range (by > 1 %) are not scored. Returns the
    ``minor_loop_law`` entry of ``diagnosis.json``.
    """
    t, v, x = (np.asarray(a, dtype=np.float64) for a in (t, v, x))
    train = np.asarray(train, dtype=bool)
    lo, hi = float(v[train].min()), float(v[train].max())
    span = hi - lo
    held = ~train & (v >= lo - 0.01 * span) & (v <= hi + 0.01 * span)
    reversals = interior_reversals(v)
    out = {"law": None, "heldout_rms_gap": {}, "unit": "m", "noise_floor": float(sigma),
           "interior_reversals": reversals, "decisive_ratio": DECISIVE_RATIO,
           "laws": {"preisach": "state-bound minor loops (relay Preisach grid, wiping-out, congruency)",
                    "duhem": "direction-bound minor loops (Coleman–Hodgdon Duhem law, no return-point memory)"}}
    if reversals < MIN_INTERIOR_REVERSALS or held.sum() < 50:
        out["note"] = (f"the record has {reversals} reversal(s) inside its voltage range and {int(held.sum())} "
                       "scored held-out samples: without minor loops both laws fit alike; record minor loops "
                       "(afmsim.diagnosis.loops.minor_loop.minor_loop_excitation)")
        return out
    dt = float((t[-1] - t[0]) / (t.size - 1))
    vc = np.clip(v, lo, hi)
    vn = (vc - 0.5 * (lo + hi)) / span
    # one relaxation per decade: the law compares two loop families beside a creep, it does not forecast one
    creep = _creep_columns(vn, creep_taus(dt, float(t[train].max() - t[0]), per_decade=1), dt)
    free = np.column_stack([np.ones_like(v), vn, creep])
    relays = drive_polarity(v, x, train) * np.hstack([relay_features(vc, lo, hi, N_LEVELS), latched_relays(vc, lo, hi)])
    preisach = _predict(free, relays, x, train)
    duhem, rate, inverse = _fit_duhem(vc, lo, hi, x, train, creep)
    gaps = {"preisach": rms((preisach - x)[held]), "duhem": rms((duhem - x)[held])}
    train_gaps = {"preisach": rms((preisach - x)[train]), "duhem": rms((duhem - x)[train])}
    winner, other = sorted(LAWS, key=gaps.get)
    ratio = gaps[other] / gaps[winner] if gaps[winner] > 0 else float("inf")
    out.update(heldout_rms_gap=gaps, train_rms_gap=train_gaps, ratio=ratio,
               duhem_relaxation={"a": rate, "p": inverse},
               heldout_scored_samples=int(held.sum()))
    if ratio >= DECISIVE_RATIO:
        out["law"] = winner
        out["note"] = (f"{winner} fits the held-out minor loops better: gap {gaps[winner] * 1e9:.1f} nm vs "
                       f"{gaps[other] * 1e9:.1f} nm ({ratio:.2f}×; noise floor {sigma * 1e9:.1f} nm)")
    else:
        out["note"] = (f"undecided: held-out gaps {gaps['preisach'] * 1e9:.1f} nm (Preisach) and "
                       f"{gaps['duhem'] * 1e9:.1f} nm (Duhem) differ by less than {DECISIVE_RATIO}×")
    return out
