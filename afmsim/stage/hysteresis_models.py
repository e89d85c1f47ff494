"""Forward (voltage → displacement) hysteresis models of the simulated piezo plant.

"No inverse crime": the compensators in :mod:`afmsim.hysteresis` are Prandtl–Ishlinskii (PI) models
built from play / one-side-play operators. The plant therefore uses *other* model families, with
the two opposite minor-loop laws:

* :class:`AsymmetricPreisach` (default) — a grid of smoothed relay hysterons over the Preisach plane
  (α = up-switching, β = down-switching voltage) with a density that is **not** a function of the
  operator width α − β alone (which is what a PI model is). The density is skewed along the
  diagonal (bias field (α+β)/2), so rising and falling branches differ beyond central symmetry.
  Minor loops are bound to the *state*: the branch after a reversal is set by the stored reversal
  points (wiping-out, congruent minor loops, return-point memory).
* :class:`AsymmetricDuhem` — a rate-independent Duhem (Coleman–Hodgdon-type) model: the branch
  slope is set by the direction of motion and the distance to the anhysteretic curve, so minor
  loops are bound to the *direction* and relax onto the major loop's branches. Its loops close
  (exactly at 0 V; periodic inputs settle on closed loops).
* :class:`LinearHysteresis` — no hysteresis, the nominal sensitivity (the "ideal" stage).

Why Preisach is the default: its relay density directly sets (i) how the loop grows with amplitude
(density vanishing like √w at the diagonal → ~1 % loops at 1 V, ~14 % at 9.1 V, datasheet row
"open-loop hysteresis", H), (ii) where along the travel the loop is wide (asymmetry, paper Fig. 2 /
Table 1, M) and (iii) wiping-out and closed minor loops — the classical description of
piezo-ceramic stacks. Which law a given stage follows is a measurement (``afmsim diagnose`` on a
loop record with minor loops, :mod:`afmsim.diagnosis.loops.minor_loop`; docs/reference-results.md).

Calibration (docs/reference-results.md, "What is calibrated to what"; :data:`afmsim.paper.CALIBRATION_TARGETS`):
both plants are scaled to 100 µm at 9.1 V (§3.2) and their loop widths set from the datasheet
(10–15 % of travel at full range). Their asymmetry (``skew``) is set from paper Table 2 — with the
defaults and all physics on, the paper's identification gives SPI 0.079 V / DIAPI 0.023 V RMS
(ratio 0.29) on the Preisach plant and SPI 0.080 V / DIAPI 0.026 V (0.33) on the Duhem plant
(paper: 0.080 / 0.021 V, 0.26). Those agreements are calibration, not evidence: with ``skew = 0``
the Preisach plant gives a ratio of 1.0.

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

__all__ = ["HysteresisModel", "AsymmetricPreisach", "AsymmetricDuhem", "LinearHysteresis", "HYSTERESIS_MODELS"]


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
def _duhem_kernel(x, width, power, end_power, skew, rate, y, x_prev, out):  # pragma: no cover - compiled
    """Duhem branch relaxation, exact per monotone step (normalised input x = u/U).

    On a step x0 → x1 in direction σ = sign(x1 − x0) the distance to the direction's bounding curve
    ``b_σ(x) = x − σ·w(x)/2`` decays as ``(x_lo/x_hi)^p · exp(−a·|x1 − x0|)``, the solution of
    ``d(y − b_σ)/d|x| = −α(x)(y − b_σ)`` with ``α(x) = a + p/x``. Composing steps gives the same
    result as one step (the factors multiply), so the output depends on the path only, not on how
    finely it was sampled: exactly rate-independent. ``y`` is the state on entry; returns it.
    """
    sigma = 0.0
    bound_prev = 0.0  # b_σ(x_prev) for the current σ: carried over, so each sample costs one bound
    for t in range(x.shape[0]):
        xt = x[t]
        if xt != x_prev:
            step_sigma = 1.0 if xt > x_prev else -1.0
            if step_sigma != sigma:
                sigma = step_sigma
                bound_prev = _bound(x_prev, sigma, width, power, end_power, skew)
            lo = max(min(xt, x_prev), 0.0)
            hi = max(max(xt, x_prev), 0.0)
            factor = 0.0
            if lo > 0.0:
                factor = np.exp(power * np.log(lo / hi) - rate * (hi - lo))
            bound = _bound(xt, sigma, width, power, end_power, skew)
            y = bound + (y - bound_prev) * factor
            bound_prev = bound
            x_prev = xt
        out[t] = y
    return y


@njit(cache=True, nogil=True)
def _bound(x, sigma, width, power, end_power, skew):  # pragma: no cover - compiled
    """Bounding curve ``x − σ·w(x)/2`` with the band ``w = W·x^p·(1 − x)^q·(1 + skew·(2x − 1))₊``."""
    xc = min(max(x, 0.0), 1.0)
    band = width * xc ** power * (1.0 - xc) ** end_power * max(1.0 + skew * (2.0 * xc - 1.0), 0.0)
    return x - 0.5 * sigma * band


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

    Parameters (targets in docs/reference-results.md, table "What is calibrated to what")
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
        the rest irreversible). Set from the loop width: 0.32 → 13.9 % of travel at 9.1 V (datasheet
        "open-loop hysteresis" 10–15 %, H).
    width_decay : float
        w0, relay-width scale as a fraction of U (0.35). A shape choice, no paper number targeted; M.
    width_power : float
        p, density ∝ (w/w0)^p near the diagonal (0.5). p > 0 makes small loops grow faster than
        Rayleigh's law: 0→1 V loop ≈ 1 % of its travel (datasheet "~2 % for small signals", H);
        p = 0 gives ~3 %. Calibrated, confidence M.
    skew : float
        Linear tilt of the density along the diagonal (0.6; > 0: more switching at high voltage). Sets
        the asymmetry that a symmetric PI cannot fit (paper Table 1: trace/retrace weights differ
        10–90 %, M). **Calibration** to paper Table 2's SPI mean RMS error 0.080 V (afmsim 0.079 V;
        with the creep γ, DIAPI 0.023 V and the ratio 0.29 follow — with skew = 0 the ratio is 1.0),
        confidence M.
    width_skew : float
        Couples width and bias: > 0 puts the wide relays at high bias. 0 (off), confidence L.
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
class AsymmetricDuhem(HysteresisModel):
    """Asymmetric Duhem (Coleman–Hodgdon-type) model: minor loops bound to the direction of motion.

    Rate-independent Duhem law in the normalised input x = u/U (U = ``u_max_V``), output
    ``y = scale · ŷ``::

        dŷ/dx = g_σ(x) + σ·α(x)·(x − ŷ),   σ = sign(dx),
        g_σ(x) = 1 − σ·w'(x)/2 − α(x)·w(x)/2,   α(x) = a + p/x,

    i.e. the branch slope is set by the direction σ and the distance ``x − ŷ`` to the anhysteretic
    line ŷ = x (Coleman & Hodgdon, Int. J. Eng. Sci. 24 (1986) 897, with a direction-dependent g);
    every branch relaxes toward the bounding curve ``b_σ(x) = x − σ·w(x)/2`` of its direction, the
    lower one rising, the upper one falling, with the band

        w(x) = W · x^p · (1 − x)^q · (1 + skew·(2x − 1))₊.

    The state is (x, ŷ, σ) only: two histories that reach the same point move on together — the
    minor-loop law opposite to Preisach's, where the branch after a reversal is fixed by the stored
    reversal points (wiping-out, congruent minor loops). The relaxation rate α = a + p/x makes the
    branches meet the band's closed end at 0 V, so every loop that returns to 0 V closes there
    exactly (from rest too), and periodic inputs settle on closed loops (no ratchet); there is no
    return-point memory inside the band. Not a Prandtl–Ishlinskii model (no inverse crime).

    Parameters (targets in docs/reference-results.md, table "What is calibrated to what")
    ----------
    sensitivity_m_per_V, calibration_amplitude_V, u_max_V : see :class:`AsymmetricPreisach`
        (100 µm at 9.1 V, paper §3.2; 10 V input range, §3.1).
    band_width : float
        W. Set from the datasheet's "open-loop hysteresis" 10–15 % of travel at full range: 0.73
        gives a 0 → 9.1 V → 0 loop 14.0 % of its travel wide (the Preisach plant: 13.9 %). H.
    band_power : float
        p, how the band opens from 0 V (and the 1/x part of the relaxation rate). 1.5, the
        Preisach plant's small-loop growth (its density ∝ √w near the diagonal). Confidence M.
    relaxation_rate : float
        a, the constant part of α (per unit x). 3.0: a 0 → 1 V loop is 2.4 % of its travel wide
        (datasheet "~2 % for small signals", H; the Preisach plant: 1.0 %). Confidence M.
    end_power : float
        q, the band closes at the top of the input range (1.0). Confidence L.
    skew : float
        Tilts the band along the travel (> 0: wider at high voltage; −0.30: wider at low voltage).
        Calibrated like the Preisach plant's ``skew``: to paper Table 2's SPI mean RMS error
        0.080 V under the identification protocol (afmsim: 0.080 V). DIAPI's 0.026 V and the
        ratio 0.33 (paper 0.021 V, 0.26) then follow: predictions on this plant. Confidence L.
    """

    sensitivity_m_per_V: float = 100e-6 / 9.1
    calibration_amplitude_V: float = 9.1
    u_max_V: float = 10.0
    band_width: float = 0.73
    band_power: float = 1.5
    relaxation_rate: float = 3.0
    end_power: float = 1.0
    skew: float = -0.30

    def __post_init__(self):
        if self.u_max_V <= 0 or self.band_width < 0 or self.band_power <= 0 or self.relaxation_rate < 0 \
                or self.end_power < 0:
            raise ValueError("u_max_V > 0, band_width ≥ 0, band_power > 0, relaxation_rate ≥ 0, end_power ≥ 0 "
                             "required")

    def band(self, u) -> np.ndarray:
        """Band width w(x) at input ``u`` (V), unscaled (the kernel's :func:`_bound` uses the same w)."""
        x = np.clip(np.asarray(u, dtype=np.float64) / self.u_max_V, 0.0, 1.0)
        return (self.band_width * x**self.band_power * (1.0 - x) ** self.end_power
                * np.clip(1.0 + self.skew * (2.0 * x - 1.0), 0.0, None))

    def branch_slope(self, u, y, rising: bool) -> np.ndarray:
        """dŷ/dx of the unscaled output ŷ at input ``u`` (V, inside (0, U)) and state ``y`` (ŷ units)
        in the given direction: ``g_σ(x) + σ·α(x)·(x − ŷ)`` (the Duhem law of the class docstring)."""
        x = np.asarray(u, dtype=np.float64) / self.u_max_V
        sigma = 1.0 if rising else -1.0
        du = 1e-6 * self.u_max_V
        dw = (self.band(u + du) - self.band(u - du)) / 2e-6
        alpha = self.relaxation_rate + self.band_power / x
        return 1.0 - sigma * dw / 2 - alpha * self.band(u) / 2 + sigma * alpha * (x - np.asarray(y, dtype=np.float64))

    def _raw(self, u):
        y = np.empty_like(u)
        _duhem_kernel(u / self.u_max_V, self.band_width, self.band_power, self.end_power, self.skew,
                      self.relaxation_rate, 0.0, 0.0, y)
        return y


@dataclass(frozen=True)
class LinearHysteresis(HysteresisModel):
    """No hysteresis: ``y = sensitivity · u`` (the ideal, hysteresis-free plant)."""

    sensitivity_m_per_V: float = 100e-6 / 9.1
    calibration_amplitude_V: float = 9.1

    def _raw(self, u):
        return u.copy()


HYSTERESIS_MODELS = {"preisach": AsymmetricPreisach, "duhem": AsymmetricDuhem, "linear": LinearHysteresis}
"""Plant hysteresis families by name (scenario ``stage.hysteresis``, ``afmsim identify --hysteresis``)."""
