"""Where is the held-out gap? Shares of the squared residual by time, travel, branch, rate and frequency."""

from __future__ import annotations

import numpy as np
from scipy.signal import welch

__all__ = ["localise", "hold_mask", "excitation_frequency", "excitation_band"]


def hold_mask(v, dt, frac=0.02) -> np.ndarray:
    """Samples where the drive is (nearly) still: |dv/dt| below ``frac`` of the record's 99.5th-percentile rate."""
    rate = np.abs(np.gradient(v, dt))
    ref = np.percentile(rate, 99.5)
    return rate <= frac * ref if ref > 0 else np.ones_like(v, dtype=bool)


def excitation_frequency(v, dt) -> float:
    """Dominant drive frequency (Hz) from the Welch spectrum of the drive (DC excluded)."""
    f, p = welch(v - v.mean(), fs=1 / dt, nperseg=min(v.size, 4096))
    p[0] = 0
    return float(f[int(np.argmax(p))]) if p.max() > 0 else float(f[1])


def excitation_band(f_exc: float) -> tuple[float, float]:
    """``where.frequency``'s band around the drive's dominant frequency ``f_exc`` (Hz): 0.5–10× it."""
    return 0.5 * f_exc, 10.0 * f_exc


def _shares(r2, groups: dict[str, np.ndarray]) -> dict:
    tot = float(r2.sum()) or 1.0
    out = {}
    for k, m in groups.items():
        out[k] = {"share": round(float(r2[m].sum()) / tot, 4), "sample_fraction": round(float(m.mean()), 4)}
    return out


def localise(t, v, x, resid, mask) -> dict:
    """Shares of ``sum(resid²)`` over the samples in ``mask`` (the held-out part).

    Each entry gives ``share`` (fraction of the squared gap) and ``sample_fraction`` (fraction of
    held-out samples), so share ≫ sample_fraction flags where the gap concentrates.
    """
    dt = float((t[-1] - t[0]) / (t.size - 1))
    r = resid[mask]
    r2 = r**2
    xx = x[mask]
    n = r.size
    half = np.arange(n) < n // 2
    hold = hold_mask(v, dt)[mask]
    dv = np.gradient(v, dt)[mask]
    where = {
        "time": _shares(r2, {"early": half, "late": ~half}),
        "motion": _shares(r2, {"hold": hold, "moving": ~hold}),
        "branch": _shares(r2, {"rising": (dv > 0) & ~hold, "falling": (dv < 0) & ~hold, "hold": hold}),
    }
    edges = np.linspace(xx.min(), xx.max(), 6)
    pos = np.clip(np.digitize(xx, edges[1:-1]), 0, 4)
    where["position"] = _shares(r2, {f"bin{k}_{(edges[k] - xx.min()) / (np.ptp(xx) or 1):.1f}-"
                                     f"{(edges[k + 1] - xx.min()) / (np.ptp(xx) or 1):.1f}": pos == k for k in range(5)})
    rate = np.abs(dv)
    moving = ~hold
    if moving.sum() >= 3:
        q = np.percentile(rate[moving], [33.3, 66.7])
        where["rate"] = _shares(r2, {"hold": hold, "slow": moving & (rate <= q[0]),
                                     "medium": moving & (rate > q[0]) & (rate <= q[1]), "fast": moving & (rate > q[1])})
    f_exc = excitation_frequency(v, dt)
    f, p = welch(r - r.mean(), fs=1 / dt, nperseg=min(n, 2048))
    ptot = float(p.sum()) or 1.0
    lo, hi = excitation_band(f_exc)
    where["frequency"] = {
        "excitation_hz": round(f_exc, 4),
        "below_excitation": round(float(p[f < lo].sum()) / ptot, 4),
        "excitation_band": round(float(p[(f >= lo) & (f <= hi)].sum()) / ptot, 4),
        "high": round(float(p[f > hi].sum()) / ptot, 4),
        "mean_offset_share": round(float(r.mean() ** 2 / (r2.mean() or 1)), 4),
    }
    return where
