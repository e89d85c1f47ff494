"""One piezo axis of the XY flexure stage: drive chain, hysteresis, creep, resonance, drift, sensor.

Signal path of :meth:`PiezoAxis.move` (all from the de-energised state at rest, t = 0 at power-up)::

    command V ─clip[0,10 V]─▶ amplifier 1st-order LP ─▶ hysteresis (V→m) ─▶ creep bank
              ─▶ 2nd-order mechanical resonance ─▶ (+ cross-coupling, in XYStage) ─▶ + thermal drift

:meth:`PiezoAxis.measure` adds capacitive-sensor noise to a true position. Every effect has an
``*_enabled`` flag in :class:`AxisParams`; all linear parts are discretised with
:func:`scipy.signal.cont2discrete` with a first-order (triangle) hold (coefficients cached per
sample interval) and run with :func:`scipy.signal.lfilter` (amplifier) and one
:func:`scipy.signal.sosfilt` pass (creep bank and resonance, in series), so the input must be
uniformly sampled. The first-order hold is exact
for the piecewise-linear drives afmsim generates and adds no delay; a zero-order hold would model a
DAC updating only at the simulation rate and lag the stage by one sample (at a 512 S/s scan grid,
1.95 ms ≈ 80 nm of fake trace/retrace shift), whereas real DACs update far faster.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
from scipy.optimize import nnls
from scipy.optimize import brentq
from scipy.signal import cont2discrete, lfilter, sosfilt

from .hysteresis_models import AsymmetricPreisach, HysteresisModel, LinearHysteresis

__all__ = ["AxisParams", "PiezoAxis", "creep_bank", "creep_sos", "resonance_sos", "check_uniform_time"]


@lru_cache(maxsize=32)
def creep_bank(gamma: float, t_ref_s: float = 0.1, tau_min_s: float = 0.01, tau_max_s: float = 1e4,
               per_decade: int = 2) -> tuple[float, np.ndarray, np.ndarray]:
    """Linear relaxation bank approximating the logarithmic creep law.

    The step response ``g(t) = g0 + Σ_k c_k (1 − exp(−t/τ_k))`` with log-spaced τ_k is fitted
    (non-negative least squares, log-spaced t from τ_min to τ_max) to
    ``1 + γ·log10(t / t_ref)`` (datasheet "creep", H), so that d(t_ref) equals the static
    hysteresis output. Returns ``(g0, c, tau)``.
    """
    n_tau = int(round(np.log10(tau_max_s / tau_min_s) * per_decade)) + 1
    tau = np.logspace(np.log10(tau_min_s), np.log10(tau_max_s), n_tau)
    t = np.logspace(np.log10(tau_min_s), np.log10(tau_max_s), 400)
    target = 1.0 + gamma * np.log10(t / t_ref_s)
    design = np.hstack([np.ones((t.size, 1)), 1.0 - np.exp(-t[:, None] / tau[None, :])])
    coef, _ = nnls(design, target)
    return float(coef[0]), coef[1:], tau


@lru_cache(maxsize=64)
def creep_sos(gamma: float, dt: float) -> np.ndarray:
    """Second-order-section form of the :func:`creep_bank` for sample interval ``dt`` (s).

    The parallel bank ``G(s) = g0 + Σ c_k/(τ_k s + 1)`` with c_k > 0 is an RC-type immittance:
    its zeros are real and interlace its poles −1/τ_k, one zero per interval between adjacent
    poles (found by :func:`scipy.optimize.brentq`) and one below the fastest pole. So G factors
    into well-conditioned first-order sections ``(s − z_k)/(s − p_k)``, each discretised with
    :func:`scipy.signal.cont2discrete` (first-order hold, see the module docstring; DC gain exact) and run in
    one :func:`scipy.signal.sosfilt` call — ~4× faster than 13 parallel ``lfilter`` calls on
    10⁶ samples.
    """
    g0, c, tau = creep_bank(gamma)
    keep = c > 0
    c, tau = c[keep], tau[keep]
    poles = np.sort(-1.0 / tau)  # most negative (fastest) first

    def gain(s):
        return g0 + np.sum(c / (tau * s + 1.0))

    zeros = []
    for lo, hi in zip(poles[:-1], poles[1:]):
        span = hi - lo
        zeros.append(brentq(gain, lo + 1e-12 * span, hi - 1e-12 * span, xtol=1e-14 * abs(lo), rtol=1e-14))
    if g0 > 0:  # last zero lies below the fastest pole
        lo = poles[0] * 2.0
        while gain(lo) < 0:
            lo *= 2.0
        zeros.append(brentq(gain, lo, poles[0] * (1 + 1e-12), xtol=1e-14 * abs(poles[0]), rtol=1e-14))
    zeros = np.sort(np.asarray(zeros))
    sections = []
    for k, pk in enumerate(poles):
        num = [1.0, -zeros[k]] if k < zeros.size else [0.0, 1.0]
        b, a, _ = cont2discrete((num, [1.0, -pk]), dt, method="foh")
        b = np.atleast_1d(np.squeeze(b))
        sections.append(np.r_[b, 0.0, a, 0.0])
    sos = np.array(sections)
    # overall gain: G(∞) = g0 for g0 > 0 (each section → 1); else match the DC gain
    dc_target = g0 + c.sum()
    dc_now = np.prod(sos[:, :3].sum(axis=1) / sos[:, 3:].sum(axis=1))
    sos[0, :3] *= dc_target / dc_now
    return sos


def check_uniform_time(t) -> float:
    """Return the sample interval of a uniformly sampled, increasing time vector (s)."""
    t = np.asarray(t, dtype=np.float64)
    if t.ndim != 1 or t.size < 2:
        raise ValueError("t must be a 1-D array with at least 2 samples")
    dt = (t[-1] - t[0]) / (t.size - 1)
    if not dt > 0:
        raise ValueError("t must be increasing")
    # cheap check on a subsample (the scan loop passes 10^6 samples)
    step = max(1, t.size // 1000)
    d = np.diff(t[::step]) / step
    if np.max(np.abs(d - dt)) > 1e-6 * dt + 1e-12:
        raise ValueError("t must be uniformly sampled (the linear dynamics are discretised once)")
    return float(dt)


def _discretise(num, den, dt):
    b, a, _ = cont2discrete((num, den), dt, method="foh")
    return np.atleast_1d(np.squeeze(b)), np.atleast_1d(a)


@lru_cache(maxsize=64)
def _amplifier_ba(bandwidth_hz: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """First-order low-pass ωc/(s + ωc), ωc = 2π·bandwidth (Hz), for sample interval ``dt`` (s)."""
    wc = 2 * np.pi * bandwidth_hz
    b, a = _discretise([wc], [1.0, wc], dt)
    b.flags.writeable = a.flags.writeable = False  # shared by every caller through the cache
    return b, a


@lru_cache(maxsize=64)
def resonance_sos(resonance_hz: float, damping_ratio: float, dt: float) -> np.ndarray:
    """One second-order section of ω0²/(s² + 2ζω0 s + ω0²) (unit DC gain) for sample interval ``dt`` (s).

    In section form so that :meth:`PiezoAxis.mechanics` runs it in the same
    :func:`scipy.signal.sosfilt` call as the :func:`creep_sos` bank (both are linear and in series).
    """
    w0 = 2 * np.pi * resonance_hz
    b, a = _discretise([w0 * w0], [1.0, 2 * damping_ratio * w0, w0 * w0], dt)
    sos = (np.r_[b, a] / a[0])[None, :]
    sos.flags.writeable = False  # shared by every caller through the cache
    return sos


@dataclass(frozen=True)
class AxisParams:
    """Parameters of one stage axis (SI units). Defaults: the paper's 100 µm XY stage.

    Attributes
    ----------
    hysteresis : HysteresisModel
        Forward rate-independent hysteresis V → m; default :class:`AsymmetricPreisach` (sensitivity
        100 µm/9.1 V from paper §3.2, loop 13.9 % of travel from the datasheet's 10–15 %; its
        asymmetry calibrated to Table 2, see :data:`afmsim.paper.CALIBRATION_TARGETS`, M).
    v_min_V, v_max_V : float
        Drive saturation (DAC/amplifier input range), 0–10 V (paper §3.1, H).
    amplifier_bandwidth_hz : float
        −3 dB corner of the HV amplifier driving the stack capacitance, modelled as a first-order
        low-pass. 3 kHz. Not in the paper or datasheet: confidence **L** (typical of 100 V
        piezo amplifiers with a few µF load); a scenario parameter.
    creep_gamma : float
        γ of the log creep law d(t) = d(0.1 s)[1 + γ log10(t/0.1 s)], per decade. 0.018: inside the
        datasheet's "creep" 0.01–0.02 (H), the value picked there is a **calibration** to paper
        Table 2's DIAPI mean RMS error 0.021 V (creep is most of what DIAPI leaves; today's plant
        gives 0.023 V at 0.018 and 0.0195 V at the datasheet midpoint 0.015). Realised by
        :func:`creep_bank` (τ from 10 ms to 10⁴ s, 2 per decade).
    drift_rate_m_per_s : float
        Deterministic thermal drift rate along this axis, m/s; displacement += rate·t (t = time since
        power-up). Default 5 nm/min (datasheet "thermal drift" 1–10 nm/min after warm-up, M).
    resonance_hz, damping_ratio : float
        First mechanical resonance of the 100 µm flexure stage, 300 Hz, ζ = 0.02 (datasheet "first
        XY resonance" 150–500 Hz unloaded / 100–300 Hz loaded, ζ 0.005–0.05, M).
    sensor_noise_m : float
        σ of the capacitive-sensor reading per sample, 10 nm. The CS05 "dynamic resolution" of
        10 nm at 8.5 kHz (paper §3.1, M) is taken as the RMS noise over the sensor's full analogue
        bandwidth; the DAQ point-samples at 1 kS/s without averaging, so that whole noise power
        aliases into the record and each sample carries σ = 10 nm (white). An averaging front end
        would give 10 nm·√(500/4250) ≈ 3.4 nm instead — set it here if so.
    *_enabled : bool
        Switch each effect off (hysteresis off = linear nominal sensitivity).
    """

    hysteresis: HysteresisModel = field(default_factory=AsymmetricPreisach)
    v_min_V: float = 0.0
    v_max_V: float = 10.0
    amplifier_bandwidth_hz: float = 3000.0
    creep_gamma: float = 0.018
    drift_rate_m_per_s: float = 5e-9 / 60.0
    resonance_hz: float = 300.0
    damping_ratio: float = 0.02
    sensor_noise_m: float = 10e-9
    saturation_enabled: bool = True
    amplifier_enabled: bool = True
    hysteresis_enabled: bool = True
    creep_enabled: bool = True
    drift_enabled: bool = True
    resonance_enabled: bool = True
    noise_enabled: bool = True

    def __post_init__(self):
        if self.v_max_V <= self.v_min_V:
            raise ValueError("v_max_V must exceed v_min_V")
        for name in ("amplifier_bandwidth_hz", "resonance_hz", "damping_ratio", "sensor_noise_m"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0")

    @property
    def sensitivity_m_per_V(self) -> float:
        """Nominal (secant, full-range) sensitivity, m/V."""
        return self.hysteresis.sensitivity_m_per_V

    @property
    def travel_m(self) -> float:
        """Rated travel, m: the peak of the calibration ramp, sensitivity × calibration amplitude
        (100 µm at 9.1 V, paper §3.1/3.2). The drive range above the calibration amplitude (9.1 to
        10 V, another 10–14 µm from rest) is the margin left for the compensators' and the
        resonance's excursions beyond an intended position inside the travel."""
        return self.hysteresis.sensitivity_m_per_V * self.hysteresis.calibration_amplitude_V


_EFFECTS = ("saturation", "amplifier", "hysteresis", "creep", "drift", "resonance", "noise")


@dataclass(frozen=True)
class PiezoAxis:
    """One simulated piezo axis; immutable, so a stage is a value and can be shared freely."""

    params: AxisParams = field(default_factory=AxisParams)

    # -- switching --------------------------------------------------------------------------
    def with_effects(self, **flags: bool) -> "PiezoAxis":
        """Copy with effects switched, e.g. ``axis.with_effects(creep=False, noise=False)``."""
        unknown = set(flags) - set(_EFFECTS)
        if unknown:
            raise ValueError(f"unknown effect(s) {sorted(unknown)}; known: {_EFFECTS}")
        return PiezoAxis(replace(self.params, **{f"{k}_enabled": bool(v) for k, v in flags.items()}))

    def hysteresis_free(self) -> "PiezoAxis":
        """The ideal axis: everything the same, hysteresis replaced by the nominal sensitivity."""
        return self.with_effects(hysteresis=False)

    # -- the chain --------------------------------------------------------------------------
    def clipped(self, v) -> np.ndarray:
        """Boolean mask of the drive samples ``v`` (V) that the saturation clips to
        [``v_min_V``, ``v_max_V``]: where the stage sits at its limit instead of following the
        command. All False when saturation is switched off (nothing is clipped then)."""
        v = np.asarray(v, dtype=np.float64)
        p = self.params
        if not p.saturation_enabled:
            return np.zeros(v.shape, dtype=bool)
        return (v < p.v_min_V) | (v > p.v_max_V)

    def drive(self, t, v) -> np.ndarray:
        """Voltage seen by the stack (V): saturation then amplifier low-pass."""
        p = self.params
        u = np.asarray(v, dtype=np.float64)
        if p.saturation_enabled:
            u = np.clip(u, p.v_min_V, p.v_max_V)
        if p.amplifier_enabled and p.amplifier_bandwidth_hz > 0:
            u = lfilter(*_amplifier_ba(float(p.amplifier_bandwidth_hz), check_uniform_time(t)), u)
        return np.ascontiguousarray(u, dtype=np.float64)

    def static_displacement(self, u) -> np.ndarray:
        """Rate-independent part, V → m (hysteresis model or the linear nominal sensitivity)."""
        p = self.params
        if p.hysteresis_enabled:
            return p.hysteresis.apply(u)
        return LinearHysteresis(p.hysteresis.sensitivity_m_per_V, p.hysteresis.calibration_amplitude_V).apply(u)

    def _creep_sections(self, t) -> list[np.ndarray]:
        """The creep bank's sections for the sample times ``t`` (s), or none when creep is off."""
        p = self.params
        if not (p.creep_enabled and p.creep_gamma != 0):
            return []
        return [creep_sos(float(p.creep_gamma), check_uniform_time(t))]

    def _resonance_sections(self, t) -> list[np.ndarray]:
        """The resonance's section for the sample times ``t`` (s), or none when it is off."""
        p = self.params
        if not (p.resonance_enabled and p.resonance_hz > 0):
            return []
        return [resonance_sos(float(p.resonance_hz), float(p.damping_ratio), check_uniform_time(t))]

    @staticmethod
    def _filter(sections: list[np.ndarray], d) -> np.ndarray:
        """``d`` (m) through the given section blocks in order, one :func:`scipy.signal.sosfilt` pass."""
        return sosfilt(np.vstack(sections), d) if sections else d

    def creep(self, t, d) -> np.ndarray:
        """Creep: relaxation bank (:func:`creep_bank`) applied to the static displacement."""
        return self._filter(self._creep_sections(t), d)

    def dynamics(self, t, d) -> np.ndarray:
        """First mechanical resonance ω0²/(s² + 2ζω0 s + ω0²), unit DC gain."""
        return self._filter(self._resonance_sections(t), d)

    def drift(self, t) -> np.ndarray:
        """Thermal drift (m) at times t (s since power-up)."""
        p = self.params
        t = np.asarray(t, dtype=np.float64)
        if not p.drift_enabled:
            return np.zeros_like(t)
        return p.drift_rate_m_per_s * t

    def mechanics(self, t, v) -> np.ndarray:
        """Displacement (m) without drift and cross-coupling, as a new array."""
        if np.shape(t) != np.shape(v):
            raise ValueError(f"t and v shapes differ: {np.shape(t)} vs {np.shape(v)}")
        # creep and resonance are linear and in series: one sosfilt pass over both
        d = self.static_displacement(self.drive(t, v))
        return self._filter(self._creep_sections(t) + self._resonance_sections(t), d)

    def move(self, t, v) -> np.ndarray:
        """True displacement (m) of this axis alone for drive v (V) at uniformly sampled t (s)."""
        return self.mechanics(t, v) + self.drift(t)

    def measure(self, x, rng: np.random.Generator) -> np.ndarray:
        """Capacitive-sensor reading of the true position x (m): x + N(0, σ²) white noise."""
        x = np.asarray(x, dtype=np.float64)
        p = self.params
        if not (p.noise_enabled and p.sensor_noise_m > 0):
            return x.copy()
        if not isinstance(rng, np.random.Generator):
            raise TypeError("rng must be a numpy.random.Generator")
        return x + p.sensor_noise_m * rng.standard_normal(x.shape)
