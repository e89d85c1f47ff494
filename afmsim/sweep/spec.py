"""Sweep files: which scenario parameters to vary, validated and expanded into runs up front.

A sweep file names a ``base`` scenario (a path relative to the sweep file, or an inline mapping)
and the parameters to vary, each by its dotted scenario path (``scan.size_um``, ``controllers``,
``stage.creep``, ``seed``, ``scan.offset_um.0``):

* ``grid``: path → list of values; the runs are the Cartesian product of the lists;
* ``random``: ``draws`` parameter sets, each parameter drawn from ``uniform: [lo, hi]``,
  ``loguniform: [lo, hi]``, ``integers: [lo, hi]`` (both ends included) or ``choice: [...]``
  by a ``numpy.random.Generator`` seeded with the sweep's ``seed``.

With both, every grid point is crossed with every random draw. Values are in the scenario's
own units (the ones its field names carry, e.g. µm for ``scan.size_um``). Every expanded run is
validated with :func:`afmsim.scenario.parse_scenario` (and its sample file, if any, checked with
:func:`afmsim.scenario.check_sample_files`) before anything runs; a bad sweep raises
:class:`SweepError` with one line naming the sweep field and, for an invalid run, the run.
The sweep's ``seed`` seeds the random draws only: each run keeps the base scenario's ``seed``
unless ``seed`` is itself swept.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Optional

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from afmsim.scenario import (IntRange, Scenario, ScenarioError, check_sample_files, load_scenario, parse_scenario,
                             read_yaml, suggest)

__all__ = ["MAX_RUNS", "Run", "Sweep", "SweepError", "load_sweep", "parse_sweep"]

MAX_RUNS = 100_000
"""Largest number of runs one sweep may expand to."""

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


class SweepError(ValueError):
    """A sweep that cannot be run; the message is one line naming the sweep field."""


class _Block(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _finite_pair(pair: tuple[float, float]) -> tuple[float, float]:
    lo, hi = pair
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"bounds must be finite, got [{lo}, {hi}]")
    if not lo < hi:
        raise ValueError(f"needs lo < hi, got [{lo}, {hi}]")
    return pair


class Distribution(_Block):
    """One random parameter: exactly one of ``uniform``, ``loguniform``, ``integers``, ``choice``."""

    uniform: Optional[tuple[float, float]] = None
    loguniform: Optional[tuple[float, float]] = None
    integers: Optional[tuple[int, int]] = None
    choice: Optional[list[Any]] = Field(None, min_length=1)

    @field_validator("uniform", "loguniform", "integers")
    @classmethod
    def _bounds(cls, pair):
        return None if pair is None else _finite_pair(pair)

    @model_validator(mode="after")
    def _exactly_one(self):
        given = [k for k in ("uniform", "loguniform", "integers", "choice") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of uniform, loguniform, integers, choice; got {given or 'none'}")
        if self.loguniform is not None and self.loguniform[0] <= 0:
            raise ValueError(f"loguniform needs 0 < lo, got {self.loguniform[0]}")
        return self

    def draw(self, rng: np.random.Generator):
        """One value drawn from ``rng`` (plain Python float, int or the chosen item)."""
        if self.uniform is not None:
            return float(rng.uniform(*self.uniform))
        if self.loguniform is not None:
            return float(np.exp(rng.uniform(*np.log(self.loguniform))))
        if self.integers is not None:
            return int(rng.integers(self.integers[0], self.integers[1], endpoint=True))
        return copy.deepcopy(self.choice[int(rng.integers(len(self.choice)))])


def _distinct(values: list) -> list:
    seen = set()
    for value in values:
        key = json.dumps(value, sort_keys=True, default=str)
        if key in seen:
            raise ValueError(f"duplicate value {_short(value)}")
        seen.add(key)
    return values


GridValues = Annotated[list[Any], Field(min_length=1), AfterValidator(_distinct)]


class RandomSpec(_Block):
    """``draws`` random parameter sets."""

    draws: IntRange(1, MAX_RUNS)
    parameters: dict[str, Distribution] = Field(min_length=1)


class SweepFile(_Block):
    """The YAML of a sweep, before expansion."""

    name: str = "sweep"
    seed: IntRange(0, 2**63 - 1) = 0
    base: Any
    grid: dict[str, GridValues] = Field(default_factory=dict)
    random: Optional[RandomSpec] = None

    @field_validator("name")
    @classmethod
    def _name(cls, name):
        if not _NAME.fullmatch(name):
            raise ValueError("must be 1–64 letters, digits, '_', '.' or '-', starting with a letter or digit")
        return name

    @field_validator("base")
    @classmethod
    def _base(cls, base):
        if isinstance(base, str) and base.strip():
            return base
        if isinstance(base, dict):
            return base
        raise ValueError(f"must be a scenario file path or an inline scenario mapping, got {type(base).__name__}")

    @model_validator(mode="after")
    def _something_to_vary(self):
        if not self.grid and self.random is None:
            raise ValueError("give 'grid' and/or 'random': nothing to vary")
        if self.random is not None:
            both = sorted(set(self.grid) & set(self.random.parameters))
            if both:
                raise ValueError(f"{both[0]} is in both grid and random")
        return self


@dataclass(frozen=True)
class Run:
    """One expanded run: its stable id, its swept values (path → value, scenario units) and scenario."""

    run_id: str
    params: dict
    scenario: Scenario


@dataclass(frozen=True)
class Sweep:
    """A validated sweep: the file's content, the base scenario and every run, in sweep order."""

    name: str
    seed: int
    base: Scenario
    parameters: tuple[str, ...]
    spec: SweepFile = field(repr=False)
    _runs: tuple[Run, ...] = field(repr=False)

    def runs(self) -> list[Run]:
        """Every run in sweep order (grid-major, then draw); identical parameter sets appear once."""
        return list(self._runs)

    def fingerprint(self) -> str:
        """Hash of the base scenario and the run ids: equal iff two sweeps do the same runs."""
        text = json.dumps({"base": self.base.model_dump(mode="json"), "runs": [r.run_id for r in self._runs]},
                          sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _short(value, width: int = 60) -> str:
    """``repr(value)`` cut to ``width`` characters (error messages stay one readable line)."""
    text = repr(value)
    return text if len(text) <= width else text[:width - 1] + "…"


def _printable(text: str) -> str:
    """``text`` with line breaks escaped, so that a message stays on one line."""
    return text.replace("\r", "\\r").replace("\n", "\\n")


def _one_line(error: ValidationError) -> str:
    first = error.errors()[0]
    where = ".".join(str(p) for p in first["loc"])
    message = first["msg"].removeprefix("Value error, ")
    value = first.get("input")
    shown = "" if first["type"] in ("value_error", "missing") or isinstance(value, (dict, list)) else f" (got {_short(value)})"
    if first["type"] == "extra_forbidden":
        known = _known_fields(first["loc"][:-1])
        hint = suggest(first["loc"][-1], known)
        message, shown = "unknown field" + (hint or (f" (known: {', '.join(known)})" if known else "")), ""
    more = f" [+{len(error.errors()) - 1} more]" if len(error.errors()) > 1 else ""
    return f"{where or 'sweep'}: {message}{shown}{more}"


def _known_fields(loc) -> list[str]:
    """Field names of the sweep-file block at ``loc``: the file itself, ``random`` or a distribution."""
    if not loc:
        return list(SweepFile.model_fields)
    if loc[0] == "random":
        return list(RandomSpec.model_fields if len(loc) == 1 else Distribution.model_fields)
    return []


def _walk(tree, path: str, field: str):
    """Check that dotted ``path`` names a node of the scenario mapping ``tree``; return its parts."""
    parts = path.split(".")
    node = tree
    for depth, part in enumerate(parts):
        here = ".".join(parts[:depth]) or "the scenario"
        if isinstance(node, dict):
            if part not in node:
                hint = suggest(part, node)
                raise SweepError(f"{field}: {here} has no field {part!r}"
                                 + (hint or f" (fields: {', '.join(node)})"))
            node = node[part]
        elif isinstance(node, list):
            if not (part.isdigit() and int(part) < len(node)):
                raise SweepError(f"{field}: {here} is a list of {len(node)}; {part!r} is not an index 0–{len(node) - 1}")
            node = node[int(part)]
        else:
            raise SweepError(f"{field}: {here} is a value, it has no field {part!r}")
    return parts


def _get(tree, parts):
    for part in parts:
        tree = tree[int(part)] if isinstance(tree, list) else tree[part]
    return tree


def _set(tree, parts, value) -> None:
    parent = _get(tree, parts[:-1])
    parent[int(parts[-1]) if isinstance(parent, list) else parts[-1]] = value


def _run_id(params: dict) -> str:
    return hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()[:12]


def _load_base(base, base_dir: Path) -> Scenario:
    if isinstance(base, dict):
        try:
            return parse_scenario(base)
        except ScenarioError as error:
            raise SweepError(f"base: {error}") from None
    path = Path(base)
    path = path if path.is_absolute() else Path(base_dir) / path
    try:
        return load_scenario(path)
    except ScenarioError as error:
        raise SweepError(f"base: {error}") from None


def _expand(spec: SweepFile, base: Scenario) -> tuple[Run, ...]:
    tree = base.model_dump(mode="json")
    sections = {path: f"grid.{path}" for path in spec.grid}
    if spec.random is not None:
        sections.update({path: f"random.parameters.{path}" for path in spec.random.parameters})
    parts = {path: _walk(tree, path, field) for path, field in sections.items()}
    for path, inner in itertools.permutations(parts, 2):
        if inner.startswith(path + "."):
            raise SweepError(f"{sections[inner]}: overlaps {sections[path]}; vary one or the other")
    draws = spec.random.draws if spec.random is not None else 1
    total = math.prod(len(values) for values in spec.grid.values()) * draws
    if total > MAX_RUNS:
        raise SweepError(f"grid/random: the sweep expands to {total:,} runs, more than the limit of {MAX_RUNS:,}")
    if spec.random is not None:
        rng = np.random.default_rng(spec.seed)
        drawn = [{path: dist.draw(rng) for path, dist in spec.random.parameters.items()} for _ in range(draws)]
    else:
        drawn = [{}]
    grid_points = [dict(zip(spec.grid, values)) for values in itertools.product(*spec.grid.values())]
    runs, seen = [], set()
    for number, values in enumerate(({**point, **draw} for point in grid_points for draw in drawn), start=1):
        data = copy.deepcopy(tree)
        for path, value in values.items():
            _set(data, parts[path], value)
        try:
            scenario = parse_scenario(data)
            check_sample_files(scenario)
        except ScenarioError as error:
            loc = str(error).split(":", 1)[0]
            culprit = next((p for p in values if loc == p or loc.startswith(p + ".")), None)
            # a cross-field message names its fields itself (scan.offset_um[0] + scan.size_um[0] ...)
            culprit = culprit or next((p for p in values if re.sub(r"\.(\d+)$", r"[\1]", p) in str(error)
                                       or p in str(error)), next(iter(values)))
            raise SweepError(f"{sections[culprit]}: run {number}/{total} ({culprit}={_short(values[culprit])}) makes an "
                             f"invalid scenario: {error}") from None
        checked = scenario.model_dump(mode="json")
        params = {path: _get(checked, parts[path]) for path in values}
        run_id = _run_id(params)
        if run_id not in seen:
            seen.add(run_id)
            runs.append(Run(run_id, params, scenario))
    return tuple(runs)


def parse_sweep(data, base_dir=".") -> Sweep:
    """Validate a sweep given as a mapping and expand its runs; ``base_dir`` resolves a ``base`` path.

    Raises :class:`SweepError` (one line) for a bad field, a base scenario that does not load, a
    dotted path that names no scenario field, more than :data:`MAX_RUNS` runs, or any run whose
    scenario is invalid.
    """
    if not isinstance(data, dict):
        raise SweepError(f"sweep: must be a mapping with base, grid and/or random, got {type(data).__name__}")
    try:
        spec = SweepFile.model_validate(data)
        base = _load_base(spec.base, Path(base_dir))
        runs = _expand(spec, base)
    except ValidationError as error:
        raise SweepError(_printable(_one_line(error))) from None
    except SweepError as error:
        raise SweepError(_printable(str(error))) from None
    parameters = tuple(spec.grid) + (tuple(spec.random.parameters) if spec.random is not None else ())
    return Sweep(spec.name, spec.seed, base, parameters, spec, runs)


def load_sweep(path) -> Sweep:
    """Read, validate and expand a sweep YAML file; raises :class:`SweepError` (one line).

    The file is read by :func:`afmsim.scenario.read_yaml`, with the limits of a scenario file
    (UTF-8, at most 1 MiB, no duplicate keys or aliases).
    """
    path = Path(path)
    try:
        data = read_yaml(path)
    except ScenarioError as error:
        raise SweepError(str(error)) from None
    return parse_sweep(data, path.parent)
