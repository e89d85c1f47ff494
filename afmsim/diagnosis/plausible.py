"""Physically plausible ranges of the candidates' fitted parameters (SI units), with their sources.

A significant candidate whose fitted parameter lies outside its range is reported as *implausible*:
the term closes part of the gap, but with a value no piezo stage / AFM shows, so it is absorbing
another mismatch (an effect outside the candidate set, a baseline that cannot follow the
hysteresis) — it is not a finding. Ranges are deliberately wider than the typical values of
``../shared/reference/physics-datasheet.md`` ("datasheet" below; confidence H/M/L as there).

Keys are ``(effect, parameter)`` as the fronts report them (loops and images share the names where
the physics is the same); a parameter not listed is not checked.
"""

from __future__ import annotations

__all__ = ["PLAUSIBLE", "Range", "implausible"]

from dataclasses import dataclass


@dataclass(frozen=True)
class Range:
    """Plausible ``[low, high]`` of a parameter (SI); ``absolute``: the bounds apply to |value|."""

    low: float
    high: float
    unit: str
    source: str
    absolute: bool = False

    def contains(self, value: float) -> bool:
        v = abs(value) if self.absolute else value
        return self.low <= v <= self.high


NM_PER_MIN = 1e-9 / 60.0

PLAUSIBLE: dict[tuple[str, str], Range] = {
    # datasheet: γ = 0.01–0.02 per decade (H); 0.5–3 %/decade covers soft and hard PZT
    ("creep", "gamma_per_decade"): Range(0.005, 0.03, "1/decade", "datasheet creep γ 1–2 %/decade (H), "
                                                                  "widened to 0.5–3 %/decade"),
    # datasheet: 1–10 nm/min after warm-up, 10–50 nm/min just after start (M)
    ("drift", "rate_m_per_s"): Range(0.0, 100 * NM_PER_MIN, "m/s", "datasheet thermal drift 1–50 nm/min (M), "
                                                                    "bound ~100 nm/min", absolute=True),
    # datasheet: 0.1–1 % for flexure stages, several % for tube scanners (M)
    ("cross_coupling", "coefficient"): Range(0.0, 0.05, "1", "datasheet X–Y coupling 0.1–1 % (flexures), "
                                                            "several % (tubes) (M): ≤ 5 %", absolute=True),
    # loops: low-frequency delay of amplifier pole + first resonance. Resonance ≥ 100 Hz (datasheet, M)
    # gives 2ζ/ω0 ≤ 0.2 ms; a high-voltage amplifier driving the piezo capacitance has ≥ ~30 Hz
    # large-signal bandwidth (L): ≤ 1/(2π·30 Hz) ≈ 5 ms
    ("dynamics", "lag_time_constant_s"): Range(0.0, 5e-3, "s", "first resonance ≥ 100 Hz (datasheet, M), "
                                                              "amplifier bandwidth ≥ ~30 Hz (L): lag ≤ 5 ms"),
    # images: first XY resonance 100–500 Hz (datasheet, M), Z resonance 1–5 kHz (L)
    ("dynamics", "resonance_hz"): Range(100.0, 5000.0, "Hz", "datasheet XY resonance 100–500 Hz, Z 1–5 kHz"),
    # datasheet: contact-mode integral gain 600–6000 1/s (M); another instrument's loop is not known, ×5 either side
    ("z_feedback", "ki_per_s"): Range(120.0, 30000.0, "1/s", "datasheet Ki 600–6000 1/s (M), ×5 either side"),
    # datasheet: MLCT apex 20 nm nominal, 60 nm max (M); worn tips up to ~100 nm
    ("tip", "apex_radius_m"): Range(0.5e-9, 100e-9, "m", "datasheet MLCT apex 20 nm nominal, 60 nm max (M); "
                                                        "worn tips ≤ ~100 nm"),
    # Z-piezo hysteresis: ~2 % of the range for small signals, 10–15 % at full range (datasheet, H);
    # trace and retrace of a line run the two branches over the Z range the line sweeps
    ("z_bow", "share_of_line_z_range"): Range(0.0, 0.15, "1", "datasheet piezo hysteresis 2 % (small signals) "
                                                               "to 10–15 % (full range) of the range swept (H)"),
}


def implausible(effect: str, params: dict) -> list[dict]:
    """The parameters of ``effect`` that lie outside :data:`PLAUSIBLE` (one dict each; [] when all fit)."""
    out = []
    for (name, key), rng in PLAUSIBLE.items():
        value = params.get(key) if name == effect else None
        if isinstance(value, (int, float)) and not rng.contains(float(value)):
            out.append({"effect": effect, "parameter": key, "value": float(value),
                        "plausible": [rng.low, rng.high] if not rng.absolute else [-rng.high, rng.high],
                        "unit": rng.unit, "source": rng.source})
    return out
