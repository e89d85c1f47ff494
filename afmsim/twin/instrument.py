"""``instrument.yaml``: a calibrated virtual twin of one real AFM, validated like a scenario.

The file is written by ``afmsim calibrate`` and read by ``afmsim predict`` and by scenarios that
name ``instrument: PATH``. Units are in the field names (µm, nm, Hz, ms); :func:`build_twin_stage`
and :func:`twin_z_feedback` convert to SI. Each stage axis is afmsim's own plant
(:class:`afmsim.stage.AsymmetricPreisach` hysteresis, log-law creep, resonance, amplifier, drift,
sensor noise), with the parameters the calibration fitted — never a Prandtl–Ishlinskii model, so
the compensators are not scored against their own model family. ``provenance`` says for each
parameter whether it was ``fitted`` (see ``calibration.json`` for its uncertainty), read from the
vendor ``header``, or left at afmsim's ``default`` because the data did not constrain it.

Bad or missing fields are rejected with one line naming the field and the allowed range
(:class:`InstrumentError`, exit 2 on the command line).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

from afmsim.scan import ZFeedback
from afmsim.scenario import IntRange, Range, ScenarioError, _one_line, read_yaml
from afmsim.stage import AsymmetricPreisach, AxisParams, PiezoAxis, XYStage

__all__ = ["Instrument", "AxisSpec", "LoopDriveSpec", "build_twin_axis", "ZLoopSpec", "ScanHabitSpec", "InstrumentError", "load_instrument",
           "parse_instrument", "dump_instrument", "build_twin_stage", "twin_z_feedback", "CALIBRATION_AMPLITUDE_V",
           "PROVENANCE_KINDS"]

UM, NM = 1e-6, 1e-9

CALIBRATION_AMPLITUDE_V = 9.1
"""Drive (V) at which an axis reaches ``travel_um`` on its first rise from rest (afmsim's stage convention)."""

PROVENANCE_KINDS = ("fitted", "header", "default")


class InstrumentError(ScenarioError):
    """An instrument file that cannot be used; the message is one line naming the field."""


class _Block(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class AxisSpec(_Block):
    """One piezo axis of the twin (afmsim's plant, :class:`afmsim.stage.AxisParams`; defaults = afmsim's stage)."""

    travel_um: Range(0.1, 1000, "µm") = 100.0
    hysteretic_fraction: Range(0, 1) = 0.32
    width_decay: Range(0.01, 5) = 0.35
    width_power: Range(0, 3) = 0.5
    skew: Range(-1, 1) = 0.6
    width_skew: Range(-5, 5) = 0.0
    reversible_curvature: Range(-0.9, 5) = 0.0
    creep_gamma_per_decade: Range(0, 0.1) = 0.018
    drift_nm_per_min: Range(-1000, 1000, "nm/min") = 5.0
    resonance_hz: Range(1, 1e6, "Hz") = 300.0
    damping_ratio: Range(0.001, 2) = 0.02
    amplifier_bandwidth_hz: Range(1, 1e7, "Hz") = 3000.0
    sensor_noise_nm: Range(0, 1000, "nm") = 10.0


class ZLoopSpec(_Block):
    """The twin's Z loop: its lag (the integral loop's time constant, 1/ki) and the height noise."""

    lag_ms: Range(0.02, 1000, "ms") = 1.0 / 3.0
    kp: Range(0, 2) = 0.1
    height_noise_nm: Range(0, 100, "nm") = 0.1


class ScanHabitSpec(_Block):
    """How the instrument runs its raster: overscan beyond the image and where the image sits in the travel."""

    overscan_fraction: Range(0, 1) = 0.0
    centre_fraction: Range(0.05, 0.95) = 0.5
    samples_per_pixel: IntRange(1, 16) = 4


class LoopDriveSpec(_Block):
    """How a loop record's drive maps onto the twin's 0–10 V drive: v_min_V → 0 V, v_max_V → 10 V; x offset at rest."""

    v_min_V: Range(-1e4, 1e4, "V")
    v_max_V: Range(-1e4, 1e4, "V")
    x_offset_um: Range(-1e4, 1e4, "µm") = 0.0

    @field_validator("v_max_V")
    @classmethod
    def _ordered(cls, v_max, info):
        if "v_min_V" in info.data and not v_max > info.data["v_min_V"]:
            raise ValueError(f"must exceed v_min_V = {info.data['v_min_V']:g} V, got {v_max:g}")
        return v_max


class Instrument(_Block):
    """A calibrated twin (see the module docstring)."""

    name: str = "instrument"
    calibrated_from: str = ""
    fast_axis: AxisSpec = AxisSpec()
    slow_axis: AxisSpec = AxisSpec()
    cross_coupling: Range(0, 0.1) = 0.005
    z_loop: ZLoopSpec = ZLoopSpec()
    scan: ScanHabitSpec = ScanHabitSpec()
    loop_drive: LoopDriveSpec | None = None
    provenance: dict[str, Literal[PROVENANCE_KINDS]] = {}

    @field_validator("provenance")
    @classmethod
    def _known_fields(cls, provenance: dict) -> dict:
        for key in provenance:
            block, _, name = key.partition(".")
            spec = {"fast_axis": AxisSpec, "slow_axis": AxisSpec, "z_loop": ZLoopSpec, "scan": ScanHabitSpec,
                    "loop_drive": LoopDriveSpec}.get(block)
            if (spec is None or name not in spec.model_fields) and key != "cross_coupling":
                raise ValueError(f"unknown parameter {key!r}; use BLOCK.FIELD of fast_axis, slow_axis, z_loop, scan")
        return provenance


def parse_instrument(data, source: str = "instrument") -> Instrument:
    """Validate an instrument given as a mapping; raises :class:`InstrumentError` (one line)."""
    if not isinstance(data, dict):
        raise InstrumentError(f"{source}: must be a mapping of blocks (fast_axis, slow_axis, z_loop, scan, …)")
    try:
        return Instrument.model_validate(data)
    except ValidationError as error:
        raise InstrumentError(f"{source}: {_one_line(error)}") from None


def load_instrument(path) -> Instrument:
    """Read and validate ``instrument.yaml``; raises :class:`InstrumentError` (one line)."""
    try:
        data = read_yaml(path)
    except ScenarioError as error:
        raise InstrumentError(str(error)) from None
    return parse_instrument(data, str(path))


def dump_instrument(instrument: Instrument, path) -> None:
    """Write ``instrument`` as human-readable YAML (block order as in :class:`Instrument`)."""
    text = ("# afmsim virtual twin of a real AFM (afmsim calibrate). Units are in the field names.\n"
            "# provenance: fitted (uncertainty in calibration.json), header (vendor file), default (not constrained)\n")
    text += yaml.safe_dump(instrument.model_dump(mode="json"), sort_keys=False, allow_unicode=True)
    Path(path).write_text(text, encoding="utf-8")


def build_twin_axis(spec: AxisSpec) -> PiezoAxis:
    """One twin axis: afmsim's piezo axis with ``spec``'s Preisach hysteresis and dynamics, drive 0–10 V."""
    hysteresis = AsymmetricPreisach(
        sensitivity_m_per_V=spec.travel_um * UM / CALIBRATION_AMPLITUDE_V, calibration_amplitude_V=CALIBRATION_AMPLITUDE_V,
        hysteretic_fraction=spec.hysteretic_fraction, width_decay=spec.width_decay, width_power=spec.width_power,
        skew=spec.skew, width_skew=spec.width_skew, reversible_curvature=spec.reversible_curvature)
    return PiezoAxis(AxisParams(hysteresis=hysteresis, amplifier_bandwidth_hz=spec.amplifier_bandwidth_hz,
                                # below 1e-6 per decade creep is nil (and its relaxation bank degenerate)
                                creep_gamma=spec.creep_gamma_per_decade if spec.creep_gamma_per_decade >= 1e-6 else 0.0,
                                drift_rate_m_per_s=spec.drift_nm_per_min * NM / 60,
                                resonance_hz=spec.resonance_hz, damping_ratio=spec.damping_ratio,
                                sensor_noise_m=spec.sensor_noise_nm * NM))


def build_twin_stage(instrument: Instrument) -> XYStage:
    """The twin's XY plant (fast axis = x, slow axis = y), all effects on."""
    return XYStage(build_twin_axis(instrument.fast_axis), build_twin_axis(instrument.slow_axis),
                   coupling_x_to_y=instrument.cross_coupling, coupling_y_to_x=instrument.cross_coupling,
                   coupling_enabled=instrument.cross_coupling > 0)


def twin_z_feedback(instrument: Instrument, loop_rate_hz: float = 50_000.0) -> ZFeedback:
    """The twin's Z loop: integral gain 1/lag, its proportional gain, height noise as deflection noise."""
    z = instrument.z_loop
    ki = 1.0 / (z.lag_ms * 1e-3)
    return ZFeedback(ki_per_s=ki, kp=z.kp, deflection_noise_m=z.height_noise_nm * NM,
                     loop_rate_hz=max(loop_rate_hz, 2.0 * ki))
