"""Forward (voltage → displacement) hysteresis models of the simulated piezo plant.

"No inverse crime": the compensators in :mod:`afmsim.hysteresis` are Prandtl–Ishlinskii (PI) models
built from play / one-side-play operators. The plant therefore uses *other* model families:

* :class:`AsymmetricPreisach` (default) — a grid of smoothed relay hysterons over the Preisach plane
  (α = up-switching, β = down-switching voltage) with a density that is **not** a function of the
  operator width α − β alone (which is what a PI model is). The density is skewed along the
  diagonal (bias field (α+β)/2), so rising and falling branches differ beyond central symmetry.
* :class:`AsymmetricBoucWen` — the first-order (n = 1) Bouc–Wen differential model, integrated
  per sample in du (hence rate-independent), with direction-dependent β, γ plus a quadratic input
  term for asymmetry.
* :class:`LinearHysteresis` — no hysteresis, the nominal sensitivity (the "ideal" stage).

Why Preisach is the default: its relay density directly sets (i) how the loop grows with amplitude
(density vanishing like √w at the diagonal → ~1 % loops at 1 V, ~14 % at 9.1 V, datasheet row
"open-loop hysteresis", H), (ii) where along the travel the loop is wide (asymmetry, paper Fig. 2 /
Table 1, M) and (iii) wiping-out and closed minor loops — the known behaviour of piezo-ceramic stacks.
With the defaults and all physics on, the paper's identification (fit SPI and DIAPI on one 1 Hz,
9.1 V cycle) gives SPI ≈ 0.082 V, DIAPI ≈ 0.021 V RMS, ratio ≈ 0.26 (paper Table 2: 0.080, 0.021,
0.26). The asymmetric Bouc–Wen alternative has a single loop shape per direction, its small-signal
loops are too wide (~4 % at 1 V), and with direction-dependent β, γ its loops do not close (≈ 10 µm
left at 0 V after one full cycle), which no real stage shows.

All models map a voltage array (V, already clipped/filtered by the amplifier) to a displacement
array (m) and start from the de-energised state (u = 0, all relays off / z = 0).
Each model is scaled so that the peak of a 0 → ``calibration_amplitude_V`` → 0 ramp equals
``sensitivity_m_per_V · calibration_amplitude_V`` (100 µm at 9.1 V by default, paper §3.1/3.2).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit

__all__ = ["HysteresisModel", "AsymmetricPreisach", "AsymmetricBoucWen", "LinearHysteresis", "HYSTERESIS_MODELS"]


# ----------------------------------------------------------------------------------------------
# Preisach kernel
# ----------------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _preisach_kernel(u, delta, mu, state, u_prev, out):  # pragma: no cover - compiled
    """Smoothed-relay Preisach model, incremental.

    Relay (i, j), i ≥ j, has up threshold α_i = (i + ½)Δ and down threshold β_j = (j + ½)Δ; its
    state s ∈ [0, 1] obeys ``s ← clip(s, r(u − α_i), r(u − β_j))`` with the unit ramp
    ``r(x) = clip(x/Δ + ½, 0, 1)`` (a relay smoothed over one grid cell, so the output is
    continuous). On a rising input only the lower bound of the rows α_i whose ramp band was
    crossed can move; on a falling input only the upper bound of the crossed columns β_j, and
    only in rows that have ever been raised (``top``: the others are still off) — so each sample
    touches O(rows crossed × N) relays instead of N²/2. The relay updates are written without
    branches (``max``/``min``; an unchanged relay adds exactly 0). ``state`` is updated in
    place; returns the last input (the memory for a continuation call).
    """
    n = mu.shape[0]
    y = 0.0
    top = -1  # highest row with a relay that is not off
    for i in range(n):
        for j in range(i + 1):
            y += mu[i, j] * state[i, j]
            if state[i, j] != 0.0:
                top = i
    for t in range(u.shape[0]):
        ut = u[t]
        if ut > u_prev:
            lo = int(np.floor(u_prev / delta))
            hi = int(np.ceil(ut / delta)) - 1
            if lo < 0:
                lo = 0
            if hi > n - 1:
                hi = n - 1
            for i in range(lo, hi + 1):
                target = min(max(ut / delta - i, 0.0), 1.0)
                for j in range(i + 1):
                    s = state[i, j]
                    raised = max(s, target)
                    y += mu[i, j] * (raised - s)
                    state[i, j] = raised
            top = max(top, hi)
        elif ut < u_prev:
            lo = int(np.floor(ut / delta))
            hi = int(np.ceil(u_prev / delta)) - 1
            if lo < 0:
                lo = 0
            if hi > n - 1:
                hi = n - 1
            for j in range(lo, min(hi, top) + 1):
                target = min(max(ut / delta - j, 0.0), 1.0)
                for i in range(j, top + 1):
                    s = state[i, j]
                    lowered = min(s, target)
                    y += mu[i, j] * (lowered - s)
                    state[i, j] = lowered
        out[t] = y
        u_prev = ut
    return u_prev


@njit(cache=True, nogil=True)
def _bouc_wen_kernel(u, a, beta_up, gamma_up, beta_dn, gamma_dn, z0, u0, out):  # pragma: no cover
    """n = 1 Bouc–Wen, dz = A du − β|du| z − γ du |z|, integrated per sample in du (rate-independent).

    Direction-dependent (β, γ). Sub-steps keep |du| ≤ 0.01 V for accuracy of the explicit update.
    Written by hand as a numba loop because it is a nonlinear ODE in u, not a linear filter.
    """
    z = z0
    u_prev = u0
    for t in range(u.shape[0]):
        du_total = u[t] - u_prev
        if du_total != 0.0:
            nsub = int(abs(du_total) / 0.01) + 1
            du = du_total / nsub
            if du > 0:
                b = beta_up
                g = gamma_up
            else:
                b = beta_dn
                g = gamma_dn
            for _ in range(nsub):
                z += a * du - b * abs(du) * z - g * du * abs(z)
        out[t] = z
        u_prev = u[t]
    return z


# ----------------------------------------------------------------------------------------------
# Models
# ----------------------------------------------------------------------------------------------
class HysteresisModel:
    """Common interface: ``apply(u) -> displacement`` (m) from the de-energised state."""

    sensitivity_m_per_V: float
    calibration_amplitude_V: float

    def _raw(self, u: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        """Unscaled output for the voltages ``u`` (V); a new array, which :meth:`apply` scales in place."""
        raise NotImplementedError

    @cached_property
    def _scale(self) -> float:
        a = self.calibration_amplitude_V
        ramp = np.linspace(0.0, a, 2001)
        peak = float(self._raw(ramp)[-1])
        return self.sensitivity_m_per_V * a / peak

    def apply(self, u) -> np.ndarray:
        """Displacement (m) for the voltage sequence ``u`` (V), starting de-energised."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        if u.ndim != 1:
            raise ValueError(f"voltage must be 1-D, got shape {u.shape}")
        out = self._raw(u)
        out *= self._scale
        return out


@dataclass(frozen=True)
class AsymmetricPreisach(HysteresisModel):
    """Asymmetric Preisach model on an ``n_levels``-level relay grid over [0, ``u_max_V``].

    Output: ``y = scale · [ (1 − h)·(u/U) · (1 + q·u/U)/(1 + q) + h·P(u) ]`` with the relay sum
    ``P(u) = Σ μ(α_i, β_j) s_ij`` normalised to 1 when all relays are on, U = ``u_max_V``.

    Density, with width w = α − β and bias c = (α + β)/2, both scaled by U::

        μ ∝ (w/w0)^p · exp(−w/w0) · (1 + skew·(2c/U − 1))_+ · (1 + width_skew·(2c/U − 1)·w/w0)_+

    Parameters (defaults calibrated against paper Fig. 2 / Table 2; see module docstring)
    ----------
    sensitivity_m_per_V : float
        Nominal sensitivity, m/V. Default 100 µm / 9.1 V ≈ 10.99 µm/V (paper §3.2: 100 µm loop at
        9.1 V; stage spec 10 µm/V, §3.1). Confidence H.
    calibration_amplitude_V : float
        Amplitude at which the major-loop peak equals sensitivity × amplitude. 9.1 V (paper §3.2). H.
    u_max_V : float
        Top of the relay grid, V (= amplifier input saturation, 10 V). H.
    n_levels : int
        Grid levels per axis of the Preisach plane (n(n+1)/2 relays). 60: cell 0.17 V; the output
        is piecewise linear between cells. Numerical choice.
    hysteretic_fraction : float
        Share h of the full-range output carried by the relay part (diagonal relays are reversible,
        the rest irreversible). Sets the loop width: 0.32 → 13.9 % of travel at 9.1 V (datasheet
        "open-loop hysteresis" 10–15 %, H).
    width_decay : float
        w0, relay-width scale as a fraction of U (0.35). Calibrated, confidence M.
    width_power : float
        p, density ∝ (w/w0)^p near the diagonal (0.5). p > 0 makes small loops grow faster than
        Rayleigh's law: 0→1 V loop ≈ 1 % of its travel (datasheet "~2 % for small signals", H);
        p = 0 gives ~3 %. Calibrated, confidence M.
    skew : float
        Linear tilt of the density along the diagonal (0.6; > 0: more switching at high voltage). Sets
        the asymmetry that a symmetric PI cannot fit (paper Table 1: trace/retrace weights differ
        10–90 %, M). Calibrated against Table 2 (SPI ≈ 0.08 V, DIAPI ≈ 0.02 V RMS), confidence M.
    width_skew : float
        Couples width and bias: > 0 puts the wide relays at high bias. Calibrated, confidence L.
    reversible_curvature : float
        q, curvature of the reversible part (stiffening/softening of the stack). Confidence L.
    """

    sensitivity_m_per_V: float = 100e-6 / 9.1
    calibration_amplitude_V: float = 9.1
    u_max_V: float = 10.0
    n_levels: int = 60
    hysteretic_fraction: float = 0.32
    width_decay: float = 0.35
    skew: float = 0.6
    width_skew: float = 0.0
    width_power: float = 0.5
    reversible_curvature: float = 0.0

    def __post_init__(self):
        if not (0.0 <= self.hysteretic_fraction <= 1.0):
            raise ValueError("hysteretic_fraction must be in [0, 1]")
        if self.n_levels < 2 or self.u_max_V <= 0 or self.width_decay <= 0:
            raise ValueError("n_levels ≥ 2, u_max_V > 0 and width_decay > 0 required")

    @cached_property
    def density(self) -> np.ndarray:
        """Relay weights μ[i, j] (i ≥ j, lower triangle), summing to 1."""
        n = self.n_levels
        lv = (np.arange(n) + 0.5) / n  # α, β as fraction of U
        a, b = np.meshgrid(lv, lv, indexing="ij")
        w = np.clip(a - b, 0.0, None)
        c = 2.0 * (a + b) / 2.0 - 1.0  # bias in [-1, 1]
        mu = (w / self.width_decay) ** self.width_power * np.exp(-w / self.width_decay)
        mu *= np.clip(1.0 + self.skew * c, 0.0, None)
        mu *= np.clip(1.0 + self.width_skew * c * w / self.width_decay, 0.0, None)
        mu = np.tril(mu)
        total = mu.sum()
        return mu / total if total > 0 else mu

    def _raw(self, u):
        n = self.n_levels
        big_u = self.u_max_V
        y = np.empty_like(u)
        if self.hysteretic_fraction > 0:
            state = np.zeros((n, n))
            _preisach_kernel(u, big_u / n, self.density, state, 0.0, y)
        else:
            y[:] = 0.0
        # x·(1 − h)·(1 + q·x)/(1 + q) + h·y with x = u/U, in place (10⁶-sample scans); q = 0 skips
        # the curvature factor, which is then exactly 1
        q = self.reversible_curvature
        out = u / big_u
        if q != 0:
            curve = q * out
            curve += 1.0
            out *= 1.0 - self.hysteretic_fraction
            out *= curve
            out /= 1.0 + q
        else:
            out *= 1.0 - self.hysteretic_fraction
        y *= self.hysteretic_fraction
        out += y
        return out


@dataclass(frozen=True)
class AsymmetricBoucWen(HysteresisModel):
    """Asymmetric, rate-independent Bouc–Wen model (n = 1).

    ``y = scale · [ u·(1 + q·u/U) − z ]``, ``dz = A du − β_d |du| z − γ_d du |z|``, with
    direction d ∈ {up, down}. Defaults give ~11 % loops at 9.1 V; they are calibrated, not
    measured (confidence L) — use as the alternative plant family in robustness studies. Known
    limitation (why it is not the default): with β_up ≠ β_down the loop does not close — a
    0 → 9.1 V → 0 cycle leaves ≈ 10 µm at 0 V (vs 1.4 µm of creep for the Preisach plant) and
    later cycles ratchet on by ≈ 0.8 µm each.

    Parameters
    ----------
    sensitivity_m_per_V, calibration_amplitude_V, u_max_V : see :class:`AsymmetricPreisach`.
    a : float  — A, dimensionless hysteretic gain.
    beta_up, gamma_up, beta_down, gamma_down : float — 1/V, loop-shape parameters per direction.
    quadratic : float — q, input nonlinearity (asymmetry of the loop's mean curve).
    """

    sensitivity_m_per_V: float = 100e-6 / 9.1
    calibration_amplitude_V: float = 9.1
    u_max_V: float = 10.0
    a: float = 0.20
    beta_up: float = 0.15
    gamma_up: float = 0.05
    beta_down: float = 0.15
    gamma_down: float = 0.0
    quadratic: float = 0.05

    def _raw(self, u):
        z = np.empty_like(u)
        _bouc_wen_kernel(u, self.a, self.beta_up, self.gamma_up, self.beta_down, self.gamma_down, 0.0, 0.0, z)
        return u * (1.0 + self.quadratic * u / self.u_max_V) - z


@dataclass(frozen=True)
class LinearHysteresis(HysteresisModel):
    """No hysteresis: ``y = sensitivity · u`` (the ideal, hysteresis-free plant)."""

    sensitivity_m_per_V: float = 100e-6 / 9.1
    calibration_amplitude_V: float = 9.1

    def _raw(self, u):
        return u.copy()


HYSTERESIS_MODELS = {"preisach": AsymmetricPreisach, "bouc_wen": AsymmetricBoucWen, "linear": LinearHysteresis}
