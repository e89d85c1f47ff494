"""The XY stage (two :class:`PiezoAxis` + cross-coupling) and the paper's identification experiment."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .axis import AxisParams, PiezoAxis
from .hysteresis_models import HYSTERESIS_MODELS, HysteresisModel

__all__ = ["XYStage", "default_stage", "triangle_wave", "identification_experiment", "IdentificationRecord"]


@dataclass(frozen=True)
class XYStage:
    """Two piezo axes plus X–Y cross-coupling.

    Attributes
    ----------
    x, y : PiezoAxis
    coupling_x_to_y, coupling_y_to_x : float
        Fraction of one axis' motion (without drift) that appears on the other:
        ``y_true += coupling_x_to_y · x_motion``. 0.5 % each (datasheet "X–Y cross-coupling"
        0.1–1 % for flexure stages, one measured 0.98 %, M).
    coupling_enabled : bool
    """

    x: PiezoAxis = field(default_factory=PiezoAxis)
    y: PiezoAxis = field(default_factory=PiezoAxis)
    coupling_x_to_y: float = 0.005
    coupling_y_to_x: float = 0.005
    coupling_enabled: bool = True

    def move(self, t, vx, vy) -> tuple[np.ndarray, np.ndarray]:
        """True positions (m) for drive voltages vx, vy (V) sampled at uniform times t (s)."""
        mx = self.x.mechanics(t, vx)
        my = self.y.mechanics(t, vy)
        # in place (10⁶-sample scans): mechanics returns new arrays
        if self.coupling_enabled:
            x_to_y = self.coupling_x_to_y * mx
            mx += self.coupling_y_to_x * my
            my += x_to_y
        mx += self.x.drift(t)
        my += self.y.drift(t)
        return mx, my

    def clipped(self, vx, vy) -> tuple[np.ndarray, np.ndarray]:
        """Masks of the X and Y drive samples (V) clipped at the amplifier limits
        (:meth:`PiezoAxis.clipped`)."""
        return self.x.clipped(vx), self.y.clipped(vy)

    def measure(self, x, y, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Sensor readings of both axes (noise drawn from ``rng``, X first)."""
        return self.x.measure(x, rng), self.y.measure(y, rng)

    def with_effects(self, coupling: bool | None = None, **flags: bool) -> "XYStage":
        """Copy with effects switched on both axes, e.g. ``stage.with_effects(creep=False)``.

        Effects: saturation, amplifier, hysteresis, creep, drift, resonance, noise (per axis) and
        coupling (stage).
        """
        new = replace(self, x=self.x.with_effects(**flags), y=self.y.with_effects(**flags))
        if coupling is not None:
            new = replace(new, coupling_enabled=bool(coupling))
        return new

    def hysteresis_free(self) -> "XYStage":
        """The ideal stage: same everything, hysteresis replaced by the linear nominal sensitivity."""
        return self.with_effects(hysteresis=False)

    def ideal(self) -> "XYStage":
        """Every effect off: position = nominal sensitivity × voltage (clipping kept off too)."""
        return self.with_effects(coupling=False, saturation=False, amplifier=False, hysteresis=False,
                                 creep=False, drift=False, resonance=False, noise=False)


def default_stage(hysteresis: str | HysteresisModel = "preisach", **axis_overrides) -> XYStage:
    """The paper's 100 µm × 100 µm stage with documented defaults (see :class:`AxisParams`).

    ``hysteresis`` picks the plant family (:data:`HYSTERESIS_MODELS`): ``"preisach"`` (default,
    state-bound minor loops), ``"duhem"`` (direction-bound minor loops), ``"linear"`` or a model
    instance. ``axis_overrides`` replace :class:`AxisParams` fields on both axes. The
    Y axis drifts at 3 nm/min (X: 5 nm/min) so that the two are distinguishable.
    """
    model = HYSTERESIS_MODELS[hysteresis]() if isinstance(hysteresis, str) else hysteresis
    px = AxisParams(hysteresis=model, **axis_overrides)
    py = replace(px, drift_rate_m_per_s=axis_overrides.get("drift_rate_m_per_s", 3e-9 / 60.0))
    return XYStage(PiezoAxis(px), PiezoAxis(py))


def triangle_wave(amplitude_V: float = 9.1, frequency_hz: float = 1.0, sample_rate_hz: float = 1000.0,
                  cycles: int = 2, offset_V: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Unipolar triangle starting at ``offset_V``, rising first to ``offset_V + amplitude_V``.

    Returns ``(t, v)`` with ``cycles·sample_rate/frequency + 1`` samples (the closing sample of the
    last cycle included), t from 0 s.
    """
    if amplitude_V < 0 or frequency_hz <= 0 or sample_rate_hz <= 0 or cycles < 1:
        raise ValueError("need amplitude ≥ 0, frequency > 0, sample rate > 0, cycles ≥ 1")
    n = int(round(cycles * sample_rate_hz / frequency_hz))
    t = np.arange(n + 1) / sample_rate_hz
    phase = (t * frequency_hz) % 1.0
    v = offset_V + amplitude_V * (1.0 - np.abs(1.0 - 2.0 * phase))
    return t, v


@dataclass(frozen=True)
class IdentificationRecord:
    """One identification run (paper §3.2): drive voltage and sensor-measured X displacement."""

    t: np.ndarray
    voltage: np.ndarray
    displacement: np.ndarray
    true_displacement: np.ndarray
    samples_per_cycle: int

    def cycle(self, k: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(displacement, voltage) of cycle k, closing sample included (0 V → peak → 0 V)."""
        n = self.samples_per_cycle
        sl = slice(k * n, (k + 1) * n + 1)
        return self.displacement[sl], self.voltage[sl]


def identification_experiment(stage: XYStage, rng: np.random.Generator, amplitude_V: float = 9.1,
                              frequency_hz: float = 1.0, sample_rate_hz: float = 1000.0,
                              cycles: int = 2) -> IdentificationRecord:
    """Paper §3.2: X driven by a unipolar triangle from rest (Y held at 0 V), X measured by the
    capacitive sensor at ``sample_rate_hz``. Noise comes from ``rng`` only."""
    t, v = triangle_wave(amplitude_V, frequency_hz, sample_rate_hz, cycles)
    x, _ = stage.move(t, v, np.zeros_like(v))
    xm = stage.x.measure(x, rng)
    return IdentificationRecord(t, v, xm, x, int(round(sample_rate_hz / frequency_hz)))
