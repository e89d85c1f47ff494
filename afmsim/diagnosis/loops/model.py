"""Forward models voltage → displacement that are linear in their parameters, and the candidate effects.

Baseline (default, ``kind="preisach"``): a smoothed-relay Preisach grid on the *recorded* voltage
range (bipolar or not, any unit scale) plus one level below it (relays that, once on, no recorded
voltage switches off) — ``x = b0 + b1·v + Σ μ_ij s_ij(v)`` with μ ≥ 0, solved by bounded linear
least squares (:func:`scipy.optimize.lsq_linear`). ``kind="symmetric"`` uses play
operators instead (a Prandtl–Ishlinskii model, centrally symmetric loops); only then is the
``asymmetry`` candidate offered.

Candidate effects (each fitted on the training part only; the hysteresis weights are refitted
jointly with the effect):

* ``drift`` — ``+ a1·(t − t0) + a2·(t − t0)²`` (2 parameters: a slow drift with curvature, e.g.
  warm-up); reported as its least-squares rate over the training part.
* ``creep`` — a bank of first-order relaxations of the hysteresis output,
  ``x = H + Σ c_k LP_τk(H)``, c_k ≥ 0, τ_k log-spaced (1/decade) from ``max(0.02 s, 5 dt)`` to the
  training span; alternated twice with the hysteresis refit (bilinear). Reported as γ, the
  normalised log-slope of its step response per decade between ``t1 = max(0.1 s, 10 dt)`` and
  ``t2 = T_train/4``.
* ``dynamics`` — first-order lag ``1/(τ s + 1)`` on the hysteresis(+creep) output, discretised
  either by Tustin (the record is a sampled smooth signal) or by a zero-order hold (half a sample
  more delay: what a lag shorter than one sample looks like after a voltage step); τ and the
  discretisation by a grid search on the training error, weights refitted. Reported as the
  low-frequency delay (comparable with a plant's 1/ω_a + 2ζ/ω_0) and the discretisation.
* ``cross_coupling`` — ``+ c·y_m`` (only with a ``y_m`` column).
* ``asymmetry`` — (only for the symmetric baseline) ``+ q2·v² + q3·v³ + Σ e_k·v·P_k(v)``: an even
  mean curve and loop widths that vary along the travel (2 + N_PLAY free terms).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.optimize import nnls
from scipy.linalg import solve_triangular
from scipy.signal import lfilter, lfilter_zi

__all__ = ["relay_features", "play_features", "ModelSpec", "FittedModel", "fit_model", "lag_filter", "dynamics_lag_filter", "lag_delay",
           "creep_gamma_from_bank", "CANDIDATES"]

CANDIDATES = ("creep", "drift", "dynamics", "cross_coupling", "asymmetry")
N_LEVELS = 16
N_PLAY = 12
#: Tikhonov weight (relative to the sample count, on unit-RMS columns) on the non-negative hysteresis
#: weights: selects a smooth relay density where the training data leave it undetermined.
RIDGE = 1e-5


@njit(cache=True, nogil=True)
def _relay_kernel(u, n, out):  # pragma: no cover - compiled
    """Smoothed relays (i ≥ j) on normalised input u ∈ [0, n]: s ← min(max(s, r(u − i)), r(u − j))."""
    k = 0
    m = u.shape[0]
    for i in range(n):
        for j in range(i + 1):
            lo0 = min(max(u[0] - i, 0.0), 1.0)
            s = lo0  # approached from below: relays whose up-threshold is passed are on
            for t in range(m):
                lo = min(max(u[t] - i, 0.0), 1.0)
                hi = min(max(u[t] - j, 0.0), 1.0)
                if s < lo:
                    s = lo
                if s > hi:
                    s = hi
                out[t, k] = s
            k += 1


def relay_features(v, v_lo, v_hi, n_levels=N_LEVELS) -> np.ndarray:
    """Relay states (M, n(n+1)/2) on a grid of ``n_levels`` over [v_lo, v_hi]."""
    u = (np.asarray(v, dtype=np.float64) - v_lo) / (v_hi - v_lo) * n_levels
    out = np.empty((u.size, n_levels * (n_levels + 1) // 2))
    _relay_kernel(np.ascontiguousarray(u), n_levels, out)
    return out


def play_features(v, v_lo, v_hi, n_play=N_PLAY) -> np.ndarray:
    """Play operators (half-widths k/n · range/2) on the centred normalised voltage."""
    from afmsim.hysteresis import play

    c = 0.5 * (v_lo + v_hi)
    u = (np.asarray(v, dtype=np.float64) - c) / (v_hi - v_lo)
    widths = np.arange(1, n_play + 1) / n_play * 0.5
    return play(u, widths, h0=u[0])


def lag_filter(tau: float, dt: float):
    """Zero-order-hold discretisation of 1/(τs + 1): y[k] = p·y[k−1] + (1 − p)·u[k−1], p = e^{−dt/τ}.

    Its delay at low frequency is τ + dt/2 (the hold adds half a sample): right for the creep
    bank's long τ, not for a lag of the order of dt (see :func:`dynamics_lag_filter`)."""
    p = float(np.exp(-dt / tau))
    return np.array([0.0, 1.0 - p]), np.array([1.0, -p])


def dynamics_lag_filter(tau: float, dt: float):
    """Bilinear (Tustin) discretisation of 1/(τs + 1), the ``dynamics`` candidate.

    The recorded voltage is a sampled smooth signal, not a held one; Tustin keeps the
    low-frequency delay at exactly τ [s] for any τ/dt, so the fitted τ compares with a plant's
    low-frequency lag (amplifier pole + resonance: 1/ω_a + 2ζ/ω_0). ``b, a`` for ``lfilter``."""
    k = 2.0 * tau / dt
    return np.array([1.0, 1.0]) / (1.0 + k), np.array([1.0, (1.0 - k) / (1.0 + k)])


LAG_DISCRETISATIONS = {"tustin": dynamics_lag_filter, "zoh": lag_filter}


def lag_delay(discretisation: str, tau: float, dt: float) -> float:
    """Low-frequency delay [s] of the discretised lag: τ (Tustin) or τ + dt/2 (zero-order hold)."""
    return float(tau + (0.5 * dt if discretisation == "zoh" else 0.0))


def _filt(b, a, cols):
    """Filter columns (axis 0) starting in steady state at the first sample."""
    cols = np.atleast_2d(cols.T).T if cols.ndim == 1 else cols
    zi = lfilter_zi(b, a)[:, None] * cols[0][None, :]
    out, _ = lfilter(b, a, cols, axis=0, zi=zi)
    return out


def creep_taus(dt: float, span: float) -> np.ndarray:
    lo = max(0.02, 5 * dt)
    hi = max(span, 2 * lo)
    n = int(np.floor(np.log10(hi / lo))) + 1
    return np.logspace(np.log10(lo), np.log10(hi), max(n, 2))


def creep_gamma_from_bank(c, taus, t1, t2) -> float:
    """Normalised per-decade log-slope of the bank's step response.

    The creep columns are ``LP_τk(H) − H``, so a unit step of H gives
    ``g(t) = (1 − Σc) + Σ c_k (1 − e^{−t/τ_k})``; returns ``(g(t2) − g(t1)) / (g(t1)·log10(t2/t1))``.
    """
    c, taus = np.asarray(c, dtype=float), np.asarray(taus, dtype=float)
    g = lambda tt: 1.0 - c.sum() + float(np.sum(c * (1 - np.exp(-tt / taus))))  # noqa: E731
    return (g(t2) - g(t1)) / (g(t1) * np.log10(t2 / t1))


@dataclass(frozen=True)
class ModelSpec:
    kind: str = "preisach"  # "preisach" | "symmetric"
    effects: tuple[str, ...] = ()


@dataclass
class FittedModel:
    spec: ModelSpec
    prediction: np.ndarray
    n_params: int
    params: dict = field(default_factory=dict)
    hysteresis: np.ndarray | None = None


class Design:
    """Feature matrices of one record, computed once and reused by every candidate fit."""

    def __init__(self, t, v, x, y, train: np.ndarray):
        self.t, self.v, self.x, self.y, self.train = t, v, x, y, train
        self.dt = float((t[-1] - t[0]) / (t.size - 1))
        # the hysteresis grid spans the *training* voltage range: relays that only the held-out
        # part could switch would have untrained weights; held-out voltages are clipped to it
        lo, hi = float(v[train].min()), float(v[train].max())
        if hi <= lo:
            raise ValueError("the drive voltage is constant over the training part of the record")
        pad = 1e-6 * (hi - lo)
        self.v_lo, self.v_hi = lo - pad, hi + pad
        self.vc = np.clip(v, self.v_lo, self.v_hi)
        self.in_range = (v >= lo - 0.01 * (hi - lo)) & (v <= hi + 0.01 * (hi - lo))
        vn = (v - 0.5 * (lo + hi)) / (hi - lo)
        self.free = np.column_stack([np.ones_like(v), vn])
        self._hyst = {}
        self.span_train = float(t[train].max() - t[0])
        self.x_scale = float(np.std(x)) or 1.0

    def hyst(self, kind: str) -> np.ndarray:
        if kind not in self._hyst:
            # one extra level below the recorded range: relays whose down-threshold no recorded voltage
            # reaches (once on, never off: the Preisach plane extends beyond the drive)
            pad = (self.v_hi - self.v_lo) / N_LEVELS
            f = relay_features(self.vc, self.v_lo - pad, self.v_hi, N_LEVELS + 1) if kind == "preisach" else \
                play_features(self.vc, self.v_lo, self.v_hi)
            self._hyst[kind] = f
        return self._hyst[kind]


def _solve(cols_free, cols_pos, target, mask):
    """min ‖[F P]w − x‖² on ``mask`` with w_P ≥ 0; returns (weights_free, weights_pos).

    Columns are scaled to unit RMS, the problem is reduced by a QR factorisation to its
    (p × p) triangular form via the Cholesky factor of AᵀA (‖A w − x‖² = ‖R w − R⁻ᵀAᵀx‖² + const), and the free weights are split
    into non-negative ± pairs so that :func:`scipy.optimize.nnls` (Lawson–Hanson) solves it.
    """
    a = np.hstack([cols_free, cols_pos])[mask]
    nf = cols_free.shape[1]
    scale = np.sqrt(np.mean(a**2, axis=0))
    scale[scale == 0] = 1.0
    a = a / scale
    # hysteresis columns that never move on the training part are indistinguishable from the offset:
    # their weights would be arbitrary (and their held-out prediction too), so they are fixed at 0
    keep = np.r_[np.ones(nf, dtype=bool), np.std(a[:, nf:], axis=0) > 1e-6]
    ak = a[:, keep]
    g = ak.T @ ak
    ridge = RIDGE * a.shape[0] * np.r_[np.zeros(nf), np.ones(int(keep[nf:].sum()))]
    g[np.diag_indices_from(g)] += ridge + 1e-12 * np.trace(g) / g.shape[0]
    r = np.linalg.cholesky(g).T  # RᵀR = AᵀA + ridge
    b = solve_triangular(r, ak.T @ target[mask], trans="T")
    big = np.hstack([r[:, :nf], -r[:, :nf], r[:, nf:]])
    z, _ = nnls(big, b, maxiter=50 * big.shape[1])
    wk = np.r_[z[:nf] - z[nf:2 * nf], z[2 * nf:]]
    w = np.zeros(a.shape[1])
    w[keep] = wk
    w /= scale
    return w[:nf], w[nf:]


def fit_model(d: Design, spec: ModelSpec) -> FittedModel:
    """Fit ``spec`` on the training mask of ``d``; the prediction covers the whole record."""
    eff = set(spec.effects)
    kind = "preisach" if spec.kind == "preisach" else "symmetric"
    hf = d.hyst(kind)
    hyst_cols = np.hstack([d.free, hf])  # free offset+linear, then non-negative hysteresis weights
    n_free_h = d.free.shape[1]
    extra = []
    names = []
    if "drift" in eff:
        tn = (d.t - d.t[0]) / (d.t[-1] - d.t[0])
        extra += [tn, tn**2]
        names += ["drift", "drift_curvature"]
    if "asymmetry" in eff and kind == "symmetric":
        # position-dependent loop shape: even/odd polynomial terms and loop widths modulated by v
        vn = d.free[:, 1]
        extra += [vn**2, vn**3, *(vn[:, None] * hf).T]
        names += ["asymmetry"] + ["_"] * (1 + hf.shape[1])
    if "cross_coupling" in eff and d.y is not None:
        extra.append(d.y)
        names.append("cross_coupling")
    extra = np.column_stack(extra) if extra else np.empty((d.t.size, 0))
    params: dict = {}
    n_params = hyst_cols.shape[1] + extra.shape[1]

    def run(lag, creep_basis=None):
        cols = hyst_cols
        if creep_basis is not None:
            cols = np.hstack([hyst_cols, creep_basis])
        if lag is not None:
            discretisation, tau = lag
            b, a = LAG_DISCRETISATIONS[discretisation](tau, d.dt)
            cols = _filt(b, a, cols)
        free = np.hstack([cols[:, :n_free_h], extra])
        pos = cols[:, n_free_h:]
        wf, wp = _solve(free, pos, d.x, d.train)
        pred = free @ wf + pos @ wp
        hyst_part = hyst_cols[:, :n_free_h] @ wf[:n_free_h] + hyst_cols[:, n_free_h:] @ wp[: hf.shape[1]]
        return pred, wf, wp, hyst_part

    def creep_cols(hpart, taus):
        return np.column_stack([_filt(*lag_filter(tau, d.dt), hpart[:, None])[:, 0] - hpart for tau in taus])

    def fit_with(lag):
        pred, wf, wp, hpart = run(lag)
        creep = None
        if "creep" in eff:
            taus = creep_taus(d.dt, d.span_train)
            for _ in range(3):
                basis = creep_cols(hpart, taus)
                pred, wf, wp, hpart_new = run(lag, basis)
                c = wp[hf.shape[1]:]
                hpart = hpart_new
            creep = (c, taus)
        return pred, wf, wp, hpart, creep

    lag = None
    if "dynamics" in eff:
        def train_error(candidate):
            return float(np.mean((fit_with(candidate)[0] - d.x)[d.train] ** 2))

        grid = np.geomspace(0.3 * d.dt, max(0.02, 3 * d.dt), 10)
        best = None
        for discretisation in LAG_DISCRETISATIONS:
            errors = {float(tau): train_error((discretisation, tau)) for tau in grid}
            k = int(np.argmin(list(errors.values())))
            # one refinement around the best grid point (geomspace keeps the end points exact)
            for tau in np.geomspace(grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)], 5):
                tau = float(tau)
                error = errors[tau] if tau in errors else train_error((discretisation, tau))
                if best is None or error < best[0]:
                    best = (error, (discretisation, tau))
        lag = best[1]
        params["dynamics"] = {"lag_time_constant_s": lag_delay(*lag, d.dt), "discretisation": lag[0]}
        n_params += 2  # τ and the discretisation
    pred, wf, wp, hpart, creep = fit_with(lag)
    for k, name in enumerate(names):
        val = float(wf[n_free_h + k])
        if name == "drift":
            span = float(d.t[-1] - d.t[0])
            a1, a2 = val / span, float(wf[n_free_h + k + 1]) / span**2
            tt = d.t[d.train] - d.t[0]
            # reported rate: least-squares slope of the fitted drift curve over the training part
            rate = float(np.polyfit(tt, a1 * tt + a2 * tt**2, 1)[0])
            params["drift"] = {"rate_m_per_s": rate, "linear_m_per_s": a1, "quadratic_m_per_s2": a2}
        elif name == "cross_coupling":
            params[name] = {"coefficient": val}
    if creep is not None:
        c, taus = creep
        t1 = max(0.1, 10 * d.dt)
        t2 = max(d.span_train / 4, 2 * t1)
        params["creep"] = {"gamma_per_decade": float(creep_gamma_from_bank(c, taus, t1, t2)), "t1_s": t1, "t2_s": t2,
                           "taus_s": [float(x) for x in taus], "weights": [float(x) for x in c]}
        n_params += len(taus)
    if "asymmetry" in eff and kind == "symmetric":
        k = names.index("asymmetry")
        params["asymmetry"] = {"quadratic_m": float(wf[n_free_h + k]), "cubic_m": float(wf[n_free_h + k + 1]),
                               "extra_terms": 2 + hf.shape[1]}
    return FittedModel(spec=spec, prediction=pred, n_params=n_params, params=params, hysteresis=hpart)
