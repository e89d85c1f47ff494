"""Reading and validating a measured loop record (``t_s, v_V, x_m`` [, ``y_m``]).

A CSV file's columns may be separated by commas, semicolons, tabs or white space (spreadsheet exports),
and a UTF-8 byte-order mark before the header is ignored, as are comment lines before it (starting
with ``#``, ``%`` or ``//``, as instrument software writes its settings). Each header names a
quantity — ``t``, ``v``, ``x``, ``y`` or a word from :data:`NAMES` (``time``, ``voltage``,
``displacement``, ``position``…; any case) — and its unit, after an underscore, in brackets or
after "in" — ``x_m``, ``x_um``, ``x [µm]``, ``t (ms)``, ``V_mV``, ``Time (s)``, ``Displacement in
nm`` — from :data:`UNITS`; values are converted to SI on reading (columns with other names are
ignored).

Every problem with the input raises :class:`ValueError` with one line that names it. Records
that are not exactly uniformly sampled (jitter ≤ 1 % of the median interval) are accepted as is
(the median interval is used by the linear filters); larger irregularity is resampled onto a
uniform grid by linear interpolation. Long records are decimated by block means to at most
:data:`MAX_SAMPLES` samples (this also averages sensor noise); the factor is reported, and the
full-rate voltage is kept (``v_fine``): a block mean of the drive lies below a turning point's peak,
so a hysteresis model must see the fine voltage and be block-averaged itself
(:class:`~afmsim.diagnosis.loops.model.Design`), not be driven by the averaged voltage.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["LoopRecord", "load_record", "block_means", "MIN_SAMPLES", "MAX_SAMPLES", "UNITS", "NAMES"]

MIN_SAMPLES = 200
MAX_SAMPLES = 8000
REQUIRED = ("t_s", "v_V", "x_m")
#: Units a CSV header may give each quantity, with their factor to SI (s, V, m).
UNITS = {
    "t": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6},
    "v": {"V": 1.0, "mV": 1e-3, "kV": 1e3},
    "x": {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "μm": 1e-6, "nm": 1e-9},
}
UNITS["y"] = UNITS["x"]
_SI_NAME = {"t": "t_s", "v": "v_V", "x": "x_m", "y": "y_m"}
#: Words a header may use for each quantity (lower case; ``x``/``y`` displacement of the driven and
#: the cross axis). "Position"/"displacement" without an axis is the driven axis.
NAMES = {
    "t": ("t", "time"),
    "v": ("v", "u", "voltage", "drive", "drive voltage", "input voltage", "piezo voltage", "applied voltage"),
    "x": ("x", "displacement", "position", "x displacement", "x position", "sensor", "x sensor",
          "displacement x", "position x"),
    "y": ("y", "y displacement", "y position", "y sensor", "displacement y", "position y", "cross axis"),
}
_QUANTITY_OF = {word: q for q, words in NAMES.items() for word in words}
_HEADER = re.compile(r"^([A-Za-z][A-Za-z \-]*?)\s*(?:_\s*|\[\s*|\(\s*|\s+in\s+)([^\]\)\s]+)\s*[\]\)]?$")
_COMMENT = ("#", "%", "//")



def block_means(a: np.ndarray, block: int) -> np.ndarray:
    """Means of ``a``'s rows (samples, axis 0) over consecutive blocks of ``block`` samples (a
    trailing part block dropped): how a long record is decimated, and what a decimated record's
    features are (:mod:`.model`, :mod:`.bouc_wen`)."""
    a = np.asarray(a)
    m = a.shape[0] // block
    return a[: m * block].reshape((m, block) + a.shape[1:]).mean(axis=1)

@dataclass(frozen=True)
class LoopRecord:
    """A validated, uniformly sampled record (SI units). ``y`` is None without a ``y_m`` column.

    ``decimation`` > 1: every sample is the mean of that many uniform full-rate samples, and
    ``v_fine`` holds the full-rate voltage (``decimation × n`` samples; None when not decimated)."""

    t: np.ndarray
    v: np.ndarray
    x: np.ndarray
    y: np.ndarray | None
    decimation: int = 1
    source: str = "arrays"
    v_fine: np.ndarray | None = None

    @property
    def dt(self) -> float:
        return float((self.t[-1] - self.t[0]) / (self.t.size - 1))

    @property
    def n(self) -> int:
        return int(self.t.size)


def _delimiter(header: str) -> str | None:
    """The header's column separator: comma, semicolon or tab (spreadsheet exports), else white space."""
    return next((d for d in (",", ";", "\t") if d in header), None)


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise ValueError(f"record file not found: {path}")
    try:
        with open(path, encoding="utf-8-sig") as fh:  # -sig: a spreadsheet's byte-order mark is not a name
            skipped, header = 0, ""
            for line in fh:
                if line.strip() and not line.lstrip().startswith(_COMMENT):
                    header = line.strip()
                    break
                skipped += 1
    except UnicodeDecodeError:
        raise ValueError(f"record {path.name} is not a text CSV file") from None
    delimiter = _delimiter(header)
    names = [h.strip() for h in header.split(delimiter)]
    columns = _header_columns(path.name, names)
    try:
        data = np.genfromtxt(path, delimiter=delimiter, skip_header=skipped + 1, dtype=np.float64, ndmin=2,
                             encoding="utf-8-sig")
    except Exception as exc:  # numpy raises ValueError for ragged rows; anything else stays one line too
        raise ValueError(f"record {path.name} is not numeric CSV: {_first_bad_row(str(exc))}") from None
    if data.ndim != 2 or data.shape[1] != len(names):
        raise ValueError(f"record {path.name}: rows do not match the {len(names)} header columns")
    return {si: data[:, k] * factor for si, (k, factor) in columns.items()}


def _first_bad_row(message: str) -> str:
    """One line from numpy's ``genfromtxt`` error: the first row it names (numpy lists every row whose
    column count differs from the first data row's, "Line #4 (got 2 columns instead of 3)", file line
    numbers, under a first line that names none), and how many more it names."""
    rows = [line.strip() for line in message.splitlines() if line.strip().startswith("Line #")]
    if not rows:
        return message.strip().splitlines()[0] if message.strip() else "unreadable rows"
    first = re.sub(r"^Line #(\d+) \(got (\d+) columns instead of (\d+)\)$",
                   r"line \1 has \2 columns where the first data row has \3", rows[0])
    return first + (f" (and {len(rows) - 1} more such rows)" if len(rows) > 1 else "")


def _header_columns(file_name: str, names: list[str]) -> dict[str, tuple[int, float]]:
    """SI column name → (column index, factor to SI) for the headers that name a quantity in a unit
    of :data:`UNITS`. Other columns are ignored; a quantity given twice is refused, and so is a
    missing one, naming any column that looked like it but had a unit not understood."""
    columns: dict[str, tuple[int, float]] = {}
    not_understood = []
    for k, name in enumerate(names):
        match = _HEADER.match(name)
        quantity = _QUANTITY_OF.get(re.sub(r"[\s\-]+", " ", match.group(1)).strip().lower()) if match else None
        if quantity is None:
            continue
        unit = match.group(2)
        if unit not in UNITS[quantity]:
            not_understood.append(f"{name!r} ({quantity} in {', '.join(UNITS[quantity])})")
            continue
        si = _SI_NAME[quantity]
        if si in columns:
            raise ValueError(f"record {file_name}: {quantity} is given twice ({names[columns[si][0]]!r} and {name!r})")
        columns[si] = (k, UNITS[quantity][unit])
    missing = [c for c in REQUIRED if c not in columns]
    if missing:
        hint = f"; units not understood: {'; '.join(not_understood)}" if not_understood else ""
        raise ValueError(f"record {file_name} lacks column(s) {missing}; header must contain t_s,v_V,x_m[,y_m] "
                         f"(or the same quantities in other units or words, e.g. x_um, t [ms], Time (s), "
                         f"Displacement (nm)), got {names}{hint}")
    return columns


def _nan_check(name: str, a: np.ndarray) -> np.ndarray:
    bad = ~np.isfinite(a)
    if not bad.any():
        return a
    # isolated single-sample gaps are interpolated; runs (≥ 2 consecutive) are refused
    run = bad[1:] & bad[:-1]
    if run.any() or bad[0] or bad[-1]:
        raise ValueError(f"column {name} contains a run of NaN/inf values ({int(bad.sum())} bad samples); "
                         "cut the record or fill the gap")
    idx = np.arange(a.size)
    out = a.copy()
    out[bad] = np.interp(idx[bad], idx[~bad], a[~bad])
    return out


def load_record(source, *, max_samples: int = MAX_SAMPLES) -> LoopRecord:
    """Validated :class:`LoopRecord` from a CSV path, a dict/mapping of columns, or a tuple ``(t, v, x[, y])``."""
    if isinstance(source, (str, Path)):
        cols = _read_csv(Path(source))
        label = str(source)
    elif isinstance(source, dict):
        missing = [c for c in REQUIRED if c not in source]
        if missing:
            raise ValueError(f"record lacks column(s) {missing}; need t_s, v_V, x_m (optional y_m)")
        cols = {k: np.asarray(source[k], dtype=np.float64) for k in (*REQUIRED, "y_m") if k in source}
        label = "arrays"
    elif isinstance(source, (tuple, list)) and len(source) in (3, 4):
        cols = dict(zip((*REQUIRED, "y_m"), (np.asarray(a, dtype=np.float64) for a in source)))
        label = "arrays"
    else:
        raise ValueError("record must be a CSV path, a dict of columns or a tuple (t, v, x[, y])")
    n = cols["t_s"].size
    for k, a in cols.items():
        if a.ndim != 1:
            raise ValueError(f"column {k} must be 1-D, got shape {a.shape}")
        if a.size != n:
            raise ValueError(f"column {k} has {a.size} samples, t_s has {n}")
    if n < MIN_SAMPLES:
        raise ValueError(f"record too short: {n} samples, need at least {MIN_SAMPLES}")
    t = cols["t_s"]
    if not np.all(np.isfinite(t)):
        raise ValueError("column t_s contains NaN/inf")
    dt_all = np.diff(t)
    if np.any(dt_all <= 0):
        k = int(np.argmax(dt_all <= 0))
        raise ValueError(f"time is not strictly increasing (t_s[{k + 1}] = {t[k + 1]!r} <= t_s[{k}] = {t[k]!r})")
    v = _nan_check("v_V", cols["v_V"])
    x = _nan_check("x_m", cols["x_m"])
    y = _nan_check("y_m", cols["y_m"]) if "y_m" in cols else None
    if np.ptp(v) == 0:
        raise ValueError("voltage v_V is constant: a loop record needs a moving drive")
    if np.ptp(x) == 0:
        raise ValueError("displacement x_m is constant")
    if y is not None and np.ptp(y) == 0:
        y = None  # a flat cross axis carries no coupling information
    med = float(np.median(dt_all))
    if np.max(np.abs(dt_all - med)) > 0.01 * med:
        tu = t[0] + med * np.arange(int(np.floor((t[-1] - t[0]) / med)) + 1)
        v, x = np.interp(tu, t, v), np.interp(tu, t, x)
        y = None if y is None else np.interp(tu, t, y)
        t = tu
    else:
        t = t[0] + med * np.arange(t.size)
    k = int(np.ceil(t.size / max_samples))
    v_fine = None
    if k > 1:
        m = t.size // k
        v_fine = np.ascontiguousarray(v[: m * k])
        t, v, x = block_means(t, k), block_means(v, k), block_means(x, k)
        y = None if y is None else block_means(y, k)
    return LoopRecord(t=np.ascontiguousarray(t), v=np.ascontiguousarray(v), x=np.ascontiguousarray(x),
                      y=None if y is None else np.ascontiguousarray(y), decimation=k if k > 1 else 1, source=label,
                      v_fine=v_fine)
