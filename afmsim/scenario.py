"""Scenario files: the YAML a user writes, validated with pydantic.

Units at this edge are the ones an AFM user thinks in and are part of every field name
(``_um``, ``_nm``, ``_V``, ``_hz``, ``_deg``); :mod:`afmsim.experiment` converts them to SI.
Unknown keys, wrong types and out-of-range values are rejected by :func:`load_scenario` with a
one-line :class:`ScenarioError` that names the field, the value and the allowed range.

Physics lives in ``sample``, ``tip``, ``stage``, ``z_stage``, ``z_feedback``, ``scan`` and
``identification``; numerical knobs that trade accuracy for speed live apart in ``numerics``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, Union

import yaml
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from afmsim.compensation import CONTROLLER_NAMES

__all__ = ["Scenario", "ScenarioError", "load_scenario", "parse_scenario"]


class ScenarioError(ValueError):
    """A scenario that cannot be run; the message is one line naming the field."""


def _ranged(kind, lo, hi, unit: str = ""):
    def check(value):
        if not (lo <= value <= hi):
            raise ValueError(f"must be in [{lo}, {hi}]{unit}, got {value}")
        return value
    return Annotated[kind, AfterValidator(check)]


def Range(lo, hi, unit: str = ""):  # noqa: N802 - reads like a type in field declarations
    """A float field constrained to [lo, hi]; the error message states the range and unit."""
    return _ranged(float, lo, hi, f" {unit}" if unit else "")


def IntRange(lo, hi):  # noqa: N802
    """An int field constrained to [lo, hi]."""
    return _ranged(int, lo, hi)


class _Block(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# ---------------------------------------------------------------- samples
class MicroLensSample(_Block):
    """PDMS spherical micro-lens array (datasheet: L confidence; defaults for a ~10–30 µm field)."""

    kind: Literal["microlens"]
    diameter_um: Range(0.5, 50, "µm") = 8.0
    sag_um: Range(0.05, 10, "µm") = 1.0
    pitch_um: Range(0.5, 100, "µm") = 12.0
    arrangement: Literal["square", "hexagonal"] = "square"


class GratingSample(_Block):
    """HS-500MG silicon grating: 500 nm steps, 5 µm period lines along y."""

    kind: Literal["grating"]
    period_um: Range(0.5, 100, "µm") = 5.0
    step_nm: Range(1, 5000, "nm") = 500.0
    duty_cycle: Range(0.05, 0.95) = 0.5
    sidewall_deg: Range(30, 90, "deg") = 70.0


class MeshSample(_Block):
    """Any triangle mesh trimesh reads (STL/OBJ/PLY), heights by ray casting."""

    kind: Literal["mesh"]
    path: Path
    unit_m: Range(1e-12, 1.0, "m") = 1e-6


class HeightMapSample(_Block):
    """A height map from ``.npy`` or ``.tiff``."""

    kind: Literal["heightmap"]
    path: Path
    pixel_size_nm: Range(0.01, 1e5, "nm")
    z_unit_m: Range(1e-12, 1.0, "m") = 1.0


SampleSpec = Annotated[Union[MicroLensSample, GratingSample, MeshSample, HeightMapSample], Field(discriminator="kind")]


# ---------------------------------------------------------------- instrument
class TipSpec(_Block):
    """Bruker MLCT silicon-nitride tip (datasheet: apex 20 nm nominal, 60 nm max; 15–25°)."""

    shape: Literal["paraboloid", "cone"] = "cone"
    apex_radius_nm: Range(1, 1000, "nm") = 20.0
    half_angle_deg: Range(5, 80, "deg") = 20.0


class StageSpec(_Block):
    """The XY plant's physics switches and parameters (SI conversions in afmsim.experiment)."""

    hysteresis: Literal["preisach", "bouc_wen"] = "preisach"
    saturation: bool = True
    amplifier: bool = True
    creep: bool = True
    drift: bool = True
    dynamics: bool = True
    cross_coupling: Range(0.0, 0.1) = 0.005
    sensor_noise: bool = True


class ZStageSpec(_Block):
    """Z stage (paper: 12 µm travel, 0.6 µm/V)."""

    hysteresis: bool = True
    sensitivity_um_per_V: Range(0.01, 10, "µm/V") = 0.6
    travel_um: Range(0.5, 100, "µm") = 12.0


class ZFeedbackSpec(_Block):
    """Contact-mode PI loop on deflection (datasheet: Ki 600–6000 s⁻¹, Kp 0–0.5, setpoint 5–50 nm)."""

    ki_per_s: Range(1, 50000, "1/s") = 3000.0
    kp: Range(0, 2) = 0.1
    setpoint_nm: Range(0.1, 500, "nm") = 20.0
    deflection_noise_nm: Range(0, 10, "nm") = 0.1


class ScanSpec(_Block):
    """Raster scan: fast axis x (trace left→right, then retrace), slow axis y."""

    size_um: tuple[Range(0.1, 100, "µm"), Range(0.1, 100, "µm")] = (30.0, 30.0)
    offset_um: tuple[Range(0, 100, "µm"), Range(0, 100, "µm")] = (35.0, 35.0)
    pixels: IntRange(16, 2048) = 256
    lines: IntRange(2, 2048) = 256
    line_rate_hz: Range(0.01, 100, "Hz") = 1.0


class IdentificationSpec(_Block):
    """The identification experiment (paper §3.2): triangle wave, capacitive sensor."""

    amplitude_V: Range(0.1, 10, "V") = 9.1
    frequency_hz: Range(0.01, 100, "Hz") = 1.0
    sample_rate_hz: Range(10, 1e5, "Hz") = 1000.0
    n_operators: IntRange(1, 50) = 10
    range: Literal["full", "scan"] = "full"


class NumericsSpec(_Block):
    """Accuracy-vs-speed knobs, apart from the physics."""

    samples_per_pixel: IntRange(1, 64) = 4
    z_loop_rate_hz: Range(1e3, 1e6, "Hz") = 50_000.0
    sample_oversampling: IntRange(1, 8) = 2
    approach_s: Range(0.01, 100, "s") = 1.0


class Scenario(_Block):
    """A complete virtual-AFM experiment."""

    name: str = "scenario"
    seed: IntRange(0, 2**63 - 1) = 0
    experiments: IntRange(1, 1000) = 10
    sample: SampleSpec
    tip: TipSpec = TipSpec()
    stage: StageSpec = StageSpec()
    z_stage: ZStageSpec = ZStageSpec()
    z_feedback: ZFeedbackSpec = ZFeedbackSpec()
    scan: ScanSpec = ScanSpec()
    identification: IdentificationSpec = IdentificationSpec()
    controllers: list[Literal[CONTROLLER_NAMES]] = Field(default_factory=lambda: ["none", "spi", "diapi", "vendor", "ideal"],
                                                         min_length=1)
    numerics: NumericsSpec = NumericsSpec()


def _one_line(error: ValidationError) -> str:
    first = error.errors()[0]
    where = ".".join(str(p) for p in first["loc"] if not (isinstance(p, str) and p in ("microlens", "grating", "mesh", "heightmap")))
    message = first["msg"].removeprefix("Value error, ")
    value = first.get("input")
    shown = "" if first["type"] in ("value_error", "missing") or isinstance(value, dict) else f" (got {value!r})"
    more = f" [+{len(error.errors()) - 1} more]" if len(error.errors()) > 1 else ""
    return f"{where or 'scenario'}: {message}{shown}{more}"


def parse_scenario(data: dict) -> Scenario:
    """Validate a scenario given as a mapping; raises :class:`ScenarioError` (one line)."""
    if not isinstance(data, dict):
        raise ScenarioError(f"scenario: must be a mapping of blocks, got {type(data).__name__}")
    try:
        return Scenario.model_validate(data)
    except ValidationError as error:
        raise ScenarioError(_one_line(error)) from None


def load_scenario(path) -> Scenario:
    """Read and validate a scenario YAML file; raises :class:`ScenarioError` (one line)."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as error:
        raise ScenarioError(f"{path}: cannot read ({error.strerror})") from None
    except yaml.YAMLError as error:
        raise ScenarioError(f"{path}: not valid YAML ({str(error).splitlines()[0]})") from None
    return parse_scenario(data)
