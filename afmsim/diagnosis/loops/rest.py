"""The sensor's noise at rest: what the record reads before its drive first moves.

The loop diagnosis measures the sensor-noise floor σ from second differences of the baseline's
training residual (:meth:`.model.Design.noise_floor`): the *white* part of the noise only. A
sensor whose noise is coloured — building vibration, acoustic pickup, an amplifier's 1/f noise, mains
hum — has more noise at the loop's own frequencies than σ says, and no model of the stage can or
should fit it. Where a record starts at rest (the drive holds its first value, before any motion,
so the stage neither moves, creeps from this record's drive nor rings), that stretch measures the
sensor's whole noise directly: the RMS of the displacement about a straight line in time (a linear
trend is a drift or the creep of an earlier drive, not noise).

It is reported beside the diagnosis (``baseline.rest_noise``; ``unexplained.against_rest``), not
used for the status: σ stays the floor of the status and of the tests. The remainder is compared
with the rest band by band (the bands of ``where.frequency``: below half the drive's dominant
frequency, 0.5–10× it, above): where it exceeds the sensor's noise at rest is where the model, not
the sensor, leaves it. A rest shorter than :data:`MIN_REST_SAMPLES` samples is not used (its RMS
would be too uncertain).

On the real record ``piezo-sine-150V-1Hz.csv`` the first 3.26 s are at 0 V: the sensor reads
23.0 nm RMS there (block means of 7 samples, as the diagnosis sees them), 1.34× the white σ of
17.2 nm; its spectrum at rest (the raw record) peaks between 9 and 27 Hz (vibration), within the
band of a 1 Hz loop's residual. The held-out remainder is 2.7× the rest's noise at the drive's
frequencies, so not all of it is the sensor's (docs/diagnosis.md, "The sensor's noise at rest").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import welch

from .localise import excitation_band, excitation_frequency
from .record import LoopRecord

__all__ = ["RestNoise", "rest_noise", "against_rest", "rest_text", "MIN_REST_SAMPLES", "REST_TOLERANCE", "COLOURED_RATIO"]

#: Fewest samples of an initial rest that measure the noise (RMS uncertainty ≈ 1/√(2n) ≈ 7 % for
#: white noise; coloured noise has fewer independent samples, so more are wanted than that).
MIN_REST_SAMPLES = 100
#: The drive is at rest while it stays within this share of its range from its first value (1 mV
#: of a 10 V drive: a smooth start leaves it within a few samples, before the stage has moved by
#: more than a fraction of its noise; at 0.5 % a cosine start at 500 S/s was "at rest" for 12 more
#: samples and the stage's first 0.4 µm of travel read as noise). A recorded drive noisier than
#: this has no rest by this rule, and none is reported.
REST_TOLERANCE = 1e-4
#: The rest's noise is called coloured above this multiple of the white σ: white noise measured
#: twice agrees to about ±10 % over ≥ 100 samples, so a larger RMS at rest is noise σ does not see.
COLOURED_RATIO = 1.2


@dataclass(frozen=True)
class RestNoise:
    """The record's initial rest: its displacement about a linear trend (m), its length and the
    ratio of its RMS to the white σ."""

    deviation: np.ndarray
    dt: float
    to_white: float

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.deviation**2)))

    @property
    def coloured(self) -> bool:
        """Whether the rest reads more noise than the white σ (by :data:`COLOURED_RATIO`)."""
        return self.to_white > COLOURED_RATIO

    def as_dict(self) -> dict:
        return {"rms": self.rms, "unit": "m", "samples": int(self.deviation.size),
                "duration_s": float(self.dt * (self.deviation.size - 1)), "to_white_noise": round(self.to_white, 3),
                "coloured": self.coloured}


def rest_noise(rec: LoopRecord, sigma: float) -> RestNoise | None:
    """The noise the record reads before its drive first moves (see the module notes), or None
    where it starts moving within :data:`MIN_REST_SAMPLES` samples or never, or reads no noise at all
    there (a sensor quantised coarser than its noise). ``sigma``: the white σ (m), > 0."""
    span = float(np.ptp(rec.v))
    moved = np.flatnonzero(np.abs(rec.v - rec.v[0]) > REST_TOLERANCE * span)
    n = int(moved[0]) if moved.size else 0
    if n < MIN_REST_SAMPLES:
        return None
    t, x = rec.t[:n] - rec.t[0], rec.x[:n]
    if not sigma > 0:
        return None
    deviation = x - np.polyval(np.polyfit(t, x, 1), t)
    rest = RestNoise(deviation, rec.dt, float(np.sqrt(np.mean(deviation**2))) / sigma)
    return rest if rest.rms > 1e-6 * float(np.ptp(rec.x)) else None


def _band_rms(signal: np.ndarray, dt: float, nperseg: int, edges: tuple[float, float]) -> dict[str, float]:
    """RMS (m) of ``signal`` below, inside and above the band ``edges`` (Hz), from its Welch spectrum."""
    f, p = welch(signal - signal.mean(), fs=1.0 / dt, nperseg=nperseg)
    df = float(f[1] - f[0])
    lo, hi = edges
    bands = {"below_excitation": f < lo, "excitation_band": (f >= lo) & (f <= hi), "high": f > hi}
    return {name: float(np.sqrt(p[m].sum() * df)) for name, m in bands.items()}


def against_rest(rest: RestNoise, v: np.ndarray, residual: np.ndarray) -> dict:
    """The held-out remainder ``residual`` (m, the scored samples in time order) beside the noise at
    rest: its RMS in rest-noise units and, band by band (``where.frequency``'s bands around the
    drive ``v``'s dominant frequency), its RMS and the rest's. ``excess`` of a band is the part of
    the remainder's RMS there that the rest's noise does not account for, √(max(r² − n², 0))."""
    nperseg = int(min(rest.deviation.size, residual.size, 2048))
    edges = excitation_band(excitation_frequency(v, rest.dt))
    remainder = _band_rms(residual, rest.dt, nperseg, edges)
    noise = _band_rms(rest.deviation, rest.dt, nperseg, edges)
    gap = float(np.sqrt(np.mean(residual**2)))
    return {"gap_to_rest_noise": round(gap / rest.rms, 3),
            "excess_rms": float(np.sqrt(max(gap**2 - rest.rms**2, 0.0))), "unit": "m",
            "bands_hz": {"below_excitation": [0.0, edges[0]], "excitation_band": list(edges),
                         "high": [edges[1], 0.5 / rest.dt]},
            "bands": {name: {"remainder_rms": remainder[name], "rest_rms": noise[name],
                             "excess_rms": float(np.sqrt(max(remainder[name] ** 2 - noise[name] ** 2, 0.0)))}
                      for name in remainder}}


def rest_text(rest: dict) -> str:
    """One summary line on the noise at rest and the baseline's gap beside it (``baseline.rest_noise``)."""
    a = rest["against"]
    colour = "coloured noise" if rest["coloured"] else "white, as the floor assumes"
    parts = []
    for name, label in (("below_excitation", "below {0:.3g} Hz"), ("excitation_band", "{0:.3g}–{1:.3g} Hz"),
                        ("high", "above {1:.3g} Hz")):
        band = a["bands"][name]
        parts.append(f"{label.format(*a['bands_hz']['excitation_band'])} {band['remainder_rms'] * 1e9:.1f} vs "
                     f"{band['rest_rms'] * 1e9:.1f} nm")
    return (f"Noise at rest: the sensor reads {rest['rms'] * 1e9:.1f} nm RMS over the first {rest['duration_s']:.3g} s, "
            f"before the drive moves ({rest['to_white_noise']:.2f}× the white noise floor: {colour}); the held-out gap is "
            f"{a['gap_to_rest_noise']:.1f}× that, {a['excess_rms'] * 1e9:.1f} nm RMS beyond it. By band, gap vs rest: "
            + "; ".join(parts) + ".")
