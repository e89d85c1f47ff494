"""Scenario files: the YAML a user writes, validated with pydantic.

Units at this edge are the ones an AFM user thinks in and are part of every field name
(``_um``, ``_nm``, ``_V``, ``_hz``, ``_deg``); :mod:`afmsim.experiment` converts them to SI.
Unknown keys, wrong types and out-of-range values are rejected by :func:`load_scenario` with a
one-line :class:`ScenarioError` that names the field, the value and the allowed range.

What counts as bad input: a number field given a bool, a string with a unit (``"30 um"``), NaN,
±inf or a value outside its range; a bool field given anything but ``true``/``false``; a name
that is not a plain file-name stem (it becomes part of the run folder's name); combinations the
simulation cannot build (micro-lens sag above half the diameter or pitch below the diameter,
grating sidewalls wider than a line, a Z-loop gain that is unstable at the loop rate, an
identification cycle with too few samples for the controllers' fits, CAPI with one operator);
fewer than 4 lines (the image scores need 4). The file
itself must be UTF-8 YAML of at most :data:`MAX_FILE_BYTES` without duplicate keys, aliases
(``*name``, which can expand without bound) or nesting deeper than :data:`MAX_DEPTH`.

Physics lives in ``sample``, ``tip``, ``stage``, ``z_stage``, ``z_feedback``, ``scan`` and
``identification``; numerical knobs that trade accuracy for speed live apart in ``numerics``.
"""

from __future__ import annotations

import difflib
import math
import re
import reprlib
from pathlib import Path
from typing import Annotated, Literal, Union

import yaml
from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, StrictBool, ValidationError,
                      field_validator, model_validator)

from afmsim.compensation import CONTROLLER_NAMES
from afmsim.hysteresis.fitting import MIN_SAMPLES_PER_WEIGHT
from afmsim.paper import IDENTIFICATION_PROTOCOL
from afmsim.samples.loaders import MAP_SUFFIXES, MESH_SUFFIXES
from afmsim.stage import HYSTERESIS_MODELS, default_stage

__all__ = ["Scenario", "ScenarioError", "load_scenario", "parse_scenario", "read_yaml", "check_sample_files",
           "suggest", "unreachable", "MAX_FILE_BYTES", "MAX_DEPTH"]

MAX_FILE_BYTES = 1 << 20
"""Largest scenario file read, bytes (1 MiB; the bundled ones are under 1 KiB)."""

MAX_DEPTH = 32
"""Deepest YAML nesting accepted (a scenario needs 3)."""

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")

# weights each controller's fit identifies, (per operator, constant): afmsim.hysteresis *.fit and
# afmsim.compensation.VendorLinearisation (cubic per branch); each needs MIN_SAMPLES_PER_WEIGHT samples
_FIT_WEIGHTS = {"spi": (1, 0), "diapi": (2, 0), "iiapi": (2, 0), "capi": (4, 0), "vendor": (0, 8)}


class ScenarioError(ValueError):
    """A scenario that cannot be run; the message is one line naming the field."""

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))


class _FieldError(ValueError):
    """A cross-field check's failure, tagged with the field (relative to its block) to blame, or
    ``None`` when the message itself names every field involved."""

    def __init__(self, field: str | None, message: str):
        super().__init__(message)
        self.field = field


def _not_bool(value):
    # pydantic would read true/false as 1/0 in a number field
    if isinstance(value, bool):
        raise ValueError(f"must be a number, got {str(value).lower()}")
    return value


def _ranged(kind, lo, hi, unit: str = ""):
    def check(value):
        if not (lo <= value <= hi):  # also false for NaN
            raise ValueError(f"must be in [{lo}, {hi}]{unit}, got {value}")
        return value
    return Annotated[kind, BeforeValidator(_not_bool), AfterValidator(check)]


def _pair_of(unit: str):
    def check(value):
        # before pydantic's own tuple check, whose message ("a valid tuple") does not say the shape
        if isinstance(value, (list, tuple)) and len(value) == 2:
            return value
        raise ValueError(f"expected [x, y] in {unit}, got {_SHORT.repr(value)}")
    return check


def Range(lo, hi, unit: str = ""):  # noqa: N802 - reads like a type in field declarations
    """A float field constrained to [lo, hi] (NaN, ±inf and bools rejected); the error states the range."""
    return _ranged(float, lo, hi, f" {unit}" if unit else "")


def IntRange(lo, hi):  # noqa: N802
    """An int field constrained to [lo, hi] (bools rejected)."""
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

    @model_validator(mode="after")
    def _buildable(self):
        if self.sag_um > self.diameter_um / 2:
            raise _FieldError("sag_um", f"must be <= diameter_um / 2 = {self.diameter_um / 2:g} µm "
                                        f"(a cap beyond a hemisphere overhangs), got {self.sag_um:g}")
        if self.pitch_um < self.diameter_um:
            raise _FieldError("pitch_um", f"must be >= diameter_um = {self.diameter_um:g} µm "
                                          f"(lenses would overlap), got {self.pitch_um:g}")
        return self


class GratingSample(_Block):
    """HS-500MG silicon grating: 500 nm steps, 5 µm period lines along y."""

    kind: Literal["grating"]
    period_um: Range(0.5, 100, "µm") = 5.0
    step_nm: Range(1, 5000, "nm") = 500.0
    duty_cycle: Range(0.05, 0.95) = 0.5
    sidewall_deg: Range(30, 90, "deg") = 70.0

    @model_validator(mode="after")
    def _buildable(self):
        # mirrors afmsim.samples.grating: each sidewall spans step / tan(angle) horizontally
        span_um = self.step_nm * 1e-3 / math.tan(math.radians(self.sidewall_deg)) if self.sidewall_deg < 90 else 0.0
        room_um = min(self.duty_cycle, 1 - self.duty_cycle) * self.period_um
        if span_um > room_um * (1 + 1e-12):
            raise _FieldError("sidewall_deg", f"sidewalls span {span_um:.3g} µm, wider than the narrower of line "
                                              f"and gap ({room_um:.3g} µm): raise sidewall_deg, lower step_nm or "
                                              f"widen period_um")
        return self


class MeshSample(_Block):
    """Any triangle mesh trimesh reads (STL/OBJ/PLY), heights by ray casting."""

    kind: Literal["mesh"]
    path: Path
    unit_m: Range(1e-12, 1.0, "m") = 1e-6

    @field_validator("path")
    @classmethod
    def _suffix(cls, path: Path) -> Path:
        return _check_suffix(path, MESH_SUFFIXES)


class HeightMapSample(_Block):
    """A height map from ``.npy`` or ``.tiff``."""

    kind: Literal["heightmap"]
    path: Path
    pixel_size_nm: Range(0.01, 1e5, "nm")
    z_unit_m: Range(1e-12, 1.0, "m") = 1.0

    @field_validator("path")
    @classmethod
    def _suffix(cls, path: Path) -> Path:
        return _check_suffix(path, MAP_SUFFIXES)


def _check_suffix(path: Path, allowed) -> Path:
    if path.suffix.lower() not in allowed:
        raise ValueError(f"file type {path.suffix or '(none)'!r} not supported; use one of {', '.join(allowed)}")
    return path


SampleSpec = Annotated[Union[MicroLensSample, GratingSample, MeshSample, HeightMapSample], Field(discriminator="kind")]


# ---------------------------------------------------------------- instrument
class TipSpec(_Block):
    """Bruker MLCT silicon-nitride tip (datasheet: apex 20 nm nominal, 60 nm max; 15–25°)."""

    shape: Literal["paraboloid", "cone"] = "cone"
    apex_radius_nm: Range(1, 1000, "nm") = 20.0
    half_angle_deg: Range(5, 80, "deg") = 20.0


class StageSpec(_Block):
    """The XY plant's physics switches and parameters (SI conversions in afmsim.experiment)."""

    hysteresis: Literal[tuple(HYSTERESIS_MODELS)] = "preisach"  # every plant family of afmsim.stage
    saturation: StrictBool = True
    amplifier: StrictBool = True
    creep: StrictBool = True
    drift: StrictBool = True
    dynamics: StrictBool = True
    cross_coupling: Range(0.0, 0.1) = 0.005
    sensor_noise: StrictBool = True


class ZStageSpec(_Block):
    """Z stage (paper: 12 µm travel, 0.6 µm/V)."""

    hysteresis: StrictBool = True
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

    size_um: Annotated[tuple[Range(0.1, 100, "µm"), Range(0.1, 100, "µm")], BeforeValidator(_pair_of("µm"))] = (30.0, 30.0)
    offset_um: Annotated[tuple[Range(0, 100, "µm"), Range(0, 100, "µm")], BeforeValidator(_pair_of("µm"))] = (35.0, 35.0)
    pixels: IntRange(16, 2048) = 256
    lines: IntRange(4, 2048) = 256
    line_rate_hz: Range(0.01, 100, "Hz") = 1.0


class IdentificationSpec(_Block):
    """The identification experiment (paper §3.2): triangle wave, capacitive sensor; the defaults
    are the paper's protocol (:data:`afmsim.paper.IDENTIFICATION_PROTOCOL`)."""

    amplitude_V: Range(0.1, 10, "V") = IDENTIFICATION_PROTOCOL["amplitude_V"]
    frequency_hz: Range(0.01, 100, "Hz") = IDENTIFICATION_PROTOCOL["frequency_hz"]
    sample_rate_hz: Range(10, 1e5, "Hz") = IDENTIFICATION_PROTOCOL["sample_rate_hz"]
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
    instrument: Union[Path, None] = None  # a twin's instrument.yaml (afmsim calibrate), relative to the scenario file

    @field_validator("name")
    @classmethod
    def _name(cls, name: str) -> str:
        # the name becomes part of the default run folder's name
        if not _NAME.fullmatch(name):
            raise ValueError("must be 1–64 letters, digits, '_', '.' or '-', starting with a letter or digit")
        return name

    @model_validator(mode="after")
    def _identifiable(self):
        n = self.identification.n_operators
        if "capi" in self.controllers and n < 2:
            raise _FieldError("identification.n_operators", f"must be >= 2 for the capi controller, got {n}")
        weights = 0
        for name in self.controllers:
            per_operator, constant = _FIT_WEIGHTS.get(name, (0, 0))
            weights = max(weights, per_operator * n + constant)
        needed = max(MIN_SAMPLES_PER_WEIGHT * weights, 2)
        ident = self.identification
        samples = round(ident.sample_rate_hz / ident.frequency_hz) + 1
        if samples < needed:
            raise _FieldError("identification.sample_rate_hz",
                              f"{ident.sample_rate_hz:g} Hz / frequency_hz {ident.frequency_hz:g} Hz gives {samples} "
                              f"samples per cycle, the controllers need >= {needed}: raise sample_rate_hz or lower "
                              f"frequency_hz")
        return self

    @model_validator(mode="after")
    def _reachable(self):
        # a twin's stage (instrument:) is checked by load_scenario, which resolves its file
        problem = None if self.instrument is not None else unreachable(self.scan, default_stage(self.stage.hysteresis))
        if problem:
            raise _FieldError(None, problem)
        return self

    @model_validator(mode="after")
    def _stable_z_loop(self):
        # mirrors afmsim.scan.zloop.track_surface: the loop runs ceil(loop rate / sample rate) steps per sample
        sample_rate_hz = 2 * self.scan.pixels * self.numerics.samples_per_pixel * self.scan.line_rate_hz
        step_s = 1.0 / (sample_rate_hz * math.ceil(self.numerics.z_loop_rate_hz / sample_rate_hz))
        if self.z_feedback.ki_per_s * step_s > 0.5:
            raise _FieldError("z_feedback.ki_per_s",
                              f"ki × Z-loop period = {self.z_feedback.ki_per_s * step_s:.3g} must be <= 0.5 "
                              f"(unstable loop): lower ki_per_s or raise numerics.z_loop_rate_hz")
        return self


def unreachable(scan: ScanSpec, stage, whose: str = "the stage") -> str | None:
    """The one-line refusal of a scan field that leaves ``stage``'s travel on an axis, else None.

    The field must lie inside each axis's rated travel (:attr:`afmsim.stage.AxisParams.travel_m`,
    100 µm by default); the drive range above it (9.1 → 10 V) is the margin for the compensators'
    and the resonance's excursions beyond an intended position, and the rest position (0 V)
    bounds the field from below (``offset_um >= 0``).
    """
    for k, (label, axis) in enumerate((("x", stage.x), ("y", stage.y))):
        offset, size = scan.offset_um[k], scan.size_um[k]
        travel_um = axis.params.travel_m / 1e-6
        if offset + size > travel_um * (1 + 1e-12):
            return (f"scan.offset_um[{k}] + scan.size_um[{k}] = {offset:g} + {size:g} = {offset + size:g} µm exceeds "
                    f"{whose} travel {travel_um:g} µm ({label}): lower offset_um or size_um")
    return None


_TAGS = ("microlens", "grating", "mesh", "heightmap")
_SHORT = reprlib.Repr()  # a bounded repr: an offending value may be huge or deeply nested
_SHORT.maxlevel, _SHORT.maxdict, _SHORT.maxlist, _SHORT.maxstring, _SHORT.maxother = 2, 3, 3, 40, 40


_SAMPLE_MODELS = {"microlens": MicroLensSample, "grating": GratingSample, "mesh": MeshSample,
                  "heightmap": HeightMapSample}


def _fields_at(loc) -> list[str]:
    """The field names of the scenario block at ``loc`` (pydantic's location, union branch included)."""
    model = Scenario
    for part in loc:
        if model is Scenario and part == "sample":
            model = None  # the union: the next part is its branch
            continue
        if model is None:
            model = _SAMPLE_MODELS.get(part)
        else:
            annotation = model.model_fields[part].annotation if part in model.model_fields else None
            model = annotation if isinstance(annotation, type) and issubclass(annotation, BaseModel) else None
        if model is None:
            return []
    return list(model.model_fields) if model is not None else []


def suggest(word: str, known) -> str:
    """``"; did you mean 'x'?"`` for the entry of ``known`` nearest ``word`` (difflib), else ``""``."""
    close = difflib.get_close_matches(str(word), [str(k) for k in known], n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def _one_line(error: ValidationError) -> str:
    first = error.errors()[0]
    more = f" [+{len(error.errors()) - 1} more]" if len(error.errors()) > 1 else ""
    cause = first.get("ctx", {}).get("error")
    if isinstance(cause, _FieldError) and cause.field is None:
        return f"{cause}{more}"
    raw_loc = [str(p) for p in first["loc"]]
    loc = list(raw_loc)
    if loc[:1] == ["sample"] and len(loc) > 1 and loc[1] in _TAGS:
        del loc[1]  # pydantic's union branch, not a key of the file
    if isinstance(cause, _FieldError):
        loc.append(cause.field)
    message = first["msg"].removeprefix("Value error, ")
    value = first.get("input")
    hint = ""
    if first["type"] == "extra_forbidden":
        known = _fields_at(raw_loc[:-1])
        hint = suggest(raw_loc[-1], known)
        message = "unknown field" + ("" if hint or not known else f" (known: {', '.join(known)})")
        value = None
    if first["type"] == "literal_error":
        allowed = re.findall(r"'([^']*)'", first.get("ctx", {}).get("expected", ""))
        message = f"must be one of {', '.join(allowed)}"
        hint = suggest(value, allowed) if isinstance(value, str) else ""
    if first["type"] in ("model_type", "model_attributes_type", "dict_type"):
        message = "must be a mapping of fields (key: value)"
    if first["type"] in ("union_tag_not_found", "union_tag_invalid"):
        loc.append("kind")
        message = f"must be one of {', '.join(_TAGS)}"
        value = value.get("kind") if first["type"] == "union_tag_invalid" else None
        hint = suggest(value, _TAGS) if isinstance(value, str) else ""
    shown = "" if first["type"] in ("value_error", "missing") or value is None else f" (got {_SHORT.repr(value)})"
    if first["type"] in ("float_parsing", "int_parsing"):
        shown += "; give a plain number, the unit is in the field name"
    return f"{'.'.join(loc) or 'scenario'}: {message}{shown}{hint}{more}"


def parse_scenario(data: dict) -> Scenario:
    """Validate a scenario given as a mapping; raises :class:`ScenarioError` (one line)."""
    if data is None:
        raise ScenarioError("scenario: empty; expected a mapping of blocks (name, sample, scan, …)")
    if not isinstance(data, dict):
        raise ScenarioError(f"scenario: must be a mapping of blocks, got {type(data).__name__}")
    try:
        return Scenario.model_validate(data)
    except ValidationError as error:
        raise ScenarioError(_one_line(error)) from None


class _ScenarioLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
    """PyYAML's safe loader (libyaml's when built with it), stricter: no duplicate keys, ``1e5`` is a float."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if isinstance(key, (str, int, float, bool)) or key is None:
                if key in seen:
                    raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep)


# YAML 1.1 reads 1e5 (no dot) as a string; scenario files mean the number.
_ScenarioLoader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+$"),
                                      list("-+0123456789"))


def _check_structure(text: str) -> None:
    """Refuse aliases (``*name``: they can expand without bound) and nesting deeper than MAX_DEPTH,
    from the parser's events, before anything is built."""
    depth = 0
    for event in yaml.parse(text, Loader=_ScenarioLoader):
        if isinstance(event, yaml.AliasEvent):
            raise yaml.MarkedYAMLError(problem=f"alias *{event.anchor} not allowed in a scenario file",
                                       problem_mark=event.start_mark)
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            if depth > MAX_DEPTH:
                raise yaml.MarkedYAMLError(problem=f"nested deeper than {MAX_DEPTH} levels",
                                           problem_mark=event.start_mark)
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1


def read_yaml(path):
    """Read a scenario-like YAML file (see the module docstring for the limits); raises :class:`ScenarioError`."""
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            raw = handle.read(MAX_FILE_BYTES + 1)
    except OSError as error:
        raise ScenarioError(f"{path}: cannot read ({error.strerror or type(error).__name__})") from None
    except ValueError as error:  # e.g. an embedded NUL byte in the path
        raise ScenarioError(f"{path!r}: cannot read ({error})") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ScenarioError(f"{path}: larger than {MAX_FILE_BYTES >> 20} MiB, not a scenario file")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise ScenarioError(f"{path}: not UTF-8 text (byte 0x{raw[error.start]:02x} at offset {error.start})") from None
    try:
        _check_structure(text)
        return yaml.load(text, Loader=_ScenarioLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.MarkedYAMLError as error:
        mark = error.problem_mark or error.context_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        what = ", ".join(part for part in (error.context, error.problem) if part)
        raise ScenarioError(f"{path}: not valid YAML{where}: {what}") from None
    except yaml.YAMLError as error:
        raise ScenarioError(f"{path}: not valid YAML ({str(error).splitlines()[0]})") from None


def load_scenario(path) -> Scenario:
    """Read and validate a scenario YAML file; raises :class:`ScenarioError` (one line).

    A relative ``instrument:`` path is taken relative to the scenario file, and the instrument file is
    validated too (:func:`afmsim.twin.load_instrument`).
    """
    scenario = parse_scenario(read_yaml(path))
    if scenario.instrument is not None:
        from afmsim.twin.instrument import build_twin_stage, load_instrument

        instrument_path = Path(path).parent / scenario.instrument
        try:
            instrument = load_instrument(instrument_path)
        except ScenarioError as error:
            raise ScenarioError(f"instrument: {error}") from None
        problem = unreachable(scenario.scan, build_twin_stage(instrument), whose="the instrument's")
        if problem:
            raise ScenarioError(problem)
        scenario = scenario.model_copy(update={"instrument": instrument_path})
    return scenario


def check_sample_files(scenario: Scenario) -> None:
    """Raise :class:`ScenarioError` if the sample file a ``mesh``/``heightmap`` scenario names is not a readable file.

    Kept out of :func:`parse_scenario` so that a written run's ``scenario.yaml`` still parses after
    the sample file has moved.
    """
    path = getattr(scenario.sample, "path", None)
    if path is None:
        return
    try:
        exists, regular = path.exists(), path.is_file()
    except (OSError, ValueError) as error:  # ValueError: an embedded NUL byte
        raise ScenarioError(f"sample.path: cannot read {str(path)!r} ({error})") from None
    if not regular:
        raise ScenarioError(f"sample.path: {str(path)!r} {'is not a regular file' if exists else 'does not exist'}")
    try:
        with open(path, "rb"):
            pass
    except OSError as error:
        raise ScenarioError(f"sample.path: cannot read {str(path)!r} ({error.strerror})") from None
