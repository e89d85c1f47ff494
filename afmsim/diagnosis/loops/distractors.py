"""Distractors: effects outside the loop diagnosis' candidate set, for open-world validation records.

None of these is a candidate of :mod:`.model` (creep, drift, dynamics, cross-coupling); a diagnosis
that meets one should report the gap as ``unexplained`` / ``partly_explained`` (or
``nothing_missing`` when it is below the noise), never as ``explained`` by a named effect.

* :func:`mains_pickup` — a 50/60 Hz sine in the displacement sensor's output (m);
* :func:`slip` — a mechanical slip: the displacement jumps by a fixed amount at one instant and
  stays there (stick–slip of a clamp or a sample mount);
* :func:`gain_change` — the sensor's sensitivity changes during the record (a linear ramp by a
  stated fraction between two times: warming electronics, a capacitive gap that changes);
* :func:`rate_dependent_width` — extra loop width that grows with the drive rate, from play
  operators whose thresholds scale with |dv/dt| (the rate-dependent Prandtl–Ishlinskii model of
  Ang, Khosla & Riviere, IEEE/ASME Trans. Mechatronics 12 (2007) 134), minus the same operators
  at rate zero: a stage whose loop is wider at fast drive than at slow drive.

Units: SI (m, s, V). Every random choice (phase) comes from the caller's seeded generator.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.ndimage import uniform_filter1d

__all__ = ["mains_pickup", "slip", "gain_change", "rate_dependent_width", "RATE_SMOOTHING_S"]

#: Window (s) of the moving average that smooths |dv/dt| before it sets the play thresholds.
RATE_SMOOTHING_S = 0.02


def mains_pickup(t, amplitude_m: float, frequency_hz: float, rng: np.random.Generator) -> np.ndarray:
    """``amplitude_m · sin(2π·frequency_hz·t + φ)`` (m), φ uniform in [0, 2π) from ``rng``."""
    if frequency_hz <= 0:
        raise ValueError(f"frequency_hz must be > 0, got {frequency_hz}")
    phase = rng.uniform(0.0, 2 * np.pi)
    return amplitude_m * np.sin(2 * np.pi * frequency_hz * np.asarray(t, dtype=float) + phase)


def slip(t, size_m: float, at_s: float) -> np.ndarray:
    """A step of ``size_m`` (m, either sign) at time ``at_s`` (s): 0 before, ``size_m`` from then on."""
    t = np.asarray(t, dtype=float)
    return np.where(t >= at_s, size_m, 0.0)


def gain_change(t, x, fraction: float, start_s: float, end_s: float) -> np.ndarray:
    """``x`` (m) read by a sensor whose sensitivity ramps linearly from 1 to ``1 + fraction``
    between ``start_s`` and ``end_s`` (constant before and after)."""
    if end_s <= start_s:
        raise ValueError(f"gain change: end_s must be > start_s, got {start_s}..{end_s}")
    t = np.asarray(t, dtype=float)
    ramp = np.clip((t - start_s) / (end_s - start_s), 0.0, 1.0)
    return np.asarray(x, dtype=float) * (1.0 + fraction * ramp)


@njit(cache=True)
def _play_varying(v, widths, scale):  # pragma: no cover - compiled
    """Play operators of half-widths ``widths·scale[k]`` at sample k, summed with unit weights."""
    out = np.empty(v.size)
    w = np.empty(widths.size)
    for i in range(widths.size):
        w[i] = v[0]
    for k in range(v.size):
        total = 0.0
        for i in range(widths.size):
            r = widths[i] * scale[k]
            w[i] = max(v[k] - r, min(v[k] + r, w[i]))
            total += w[i]
        out[k] = total
    return out


def rate_dependent_width(t, v, width_m: float, *, n_operators: int = 8) -> np.ndarray:
    """Extra displacement (m) whose loop half-width grows with the drive rate.

    ``Σ_i [P_{r_i·ρ(t)}(v) − P_{r_i}(v)]`` scaled to metres, with play operators P of half-widths
    ``r_i`` (1/n … 1 of 0.1·range(v)) and ``ρ = 1 + |dv/dt| / max|dv/dt|`` (|dv/dt| averaged over
    :data:`RATE_SMOOTHING_S`). On a rising branch the term is ``−Σ r_i (ρ − 1)``, on a falling one
    ``+Σ r_i (ρ − 1)`` (the loop widens in the sense of a piezo loop: rising below falling); it is
    scaled so that this is ``width_m`` at the record's fastest drive and vanishes at slow drive.
    """
    t, v = np.asarray(t, dtype=float), np.asarray(v, dtype=float)
    dt = float((t[-1] - t[0]) / (t.size - 1))
    rate = np.abs(np.gradient(v, dt))
    rate = uniform_filter1d(rate, max(1, int(round(RATE_SMOOTHING_S / dt))), mode="nearest")
    top = float(rate.max())
    if top <= 0:
        return np.zeros_like(v)
    widths = 0.1 * np.ptp(v) * np.arange(1, n_operators + 1) / n_operators
    rho = 1.0 + rate / top
    extra = _play_varying(v, widths, rho) - _play_varying(v, widths, np.ones_like(v))
    return extra * width_m / widths.sum()
