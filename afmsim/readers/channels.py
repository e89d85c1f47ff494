"""What every reader returns: :class:`Channel`, :class:`AfmFile`, :class:`ReaderError`, and the
vendor-neutral rules that name a channel's quantity, direction and SI unit.

Conventions (all formats): ``Channel.data`` is float64 ``(lines, pixels)`` in SI units, row 0 = the
first line scanned, columns = intended x left → right in *both* directions (a backward scan stored
right → left is re-ordered). ``size_m`` is (x = fast axis, y = slow axis) in metres.
``line_time_s`` is the duration of ONE scan direction (one trace), so afmsim's line rate
(one line = trace + retrace) is ``1 / (2 · line_time_s)``; each reader says how it gets it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

__all__ = ["Channel", "AfmFile", "ReaderError", "quantity_of", "split_direction", "to_si", "leading_number", "scanned_lines", "reversed_lines",
           "TRACE_DIRECTIONS", "RETRACE_DIRECTIONS"]

TRACE_DIRECTIONS = ("forward", "trace")
RETRACE_DIRECTIONS = ("backward", "retrace")


class ReaderError(ValueError):
    """A file that cannot be read as an AFM image file; the message is one line naming the file."""


@dataclass(frozen=True)
class Channel:
    """One recorded image of one scan direction.

    Attributes
    ----------
    name : str
        The vendor's channel name (``"Topography"``, ``"Z-Axis"``, ``"HeightRetrace"`` less the
        direction word), unchanged otherwise.
    direction : str
        As the vendor calls it: ``forward``/``backward`` or ``trace``/``retrace``; ``""`` if none.
    quantity : str
        ``height``, ``deflection``, ``amplitude``, ``phase``, ``lateral``, ``current`` or ``other``.
    unit : str
        SI unit of ``data`` (``m``, ``V``, ``deg``, ``A``, ``N``, ``""``…).
    data : ndarray (lines, pixels)
        Values in ``unit``; row 0 = first line scanned; columns left → right.
    size_m : (float, float)
        Scan window width (x, fast axis) and height (y, slow axis), m.
    line_time_s : float or None
        Duration of one scan direction, s, where the file gives it.
    offset_m : (float, float) or None
        Position of the window's lower-left corner (outer corner of pixel [0, 0]), m, where the
        file gives one (``.gwy`` ``xoff``/``yoff``, afmsim's ``.npz``); stage coordinates only in
        afmsim's own files.
    """

    name: str
    direction: str
    quantity: str
    unit: str
    data: np.ndarray = field(repr=False)
    size_m: tuple[float, float]
    line_time_s: float | None
    offset_m: tuple[float, float] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(lines, pixels)."""
        return self.data.shape

    def summary(self) -> dict:
        """The JSON-serialisable facts ``afmsim inspect --json`` prints for this channel."""
        return {"name": self.name, "direction": self.direction, "quantity": self.quantity, "unit": self.unit,
                "shape": [int(n) for n in self.shape], "size_m": [float(v) for v in self.size_m],
                "line_time_s": self.line_time_s}


@dataclass(frozen=True)
class AfmFile:
    """An AFM file's channels and its header facts (``metadata`` is JSON-serialisable)."""

    path: Path
    format: str
    channels: tuple[Channel, ...]
    metadata: dict


def reversed_lines(afm: AfmFile) -> AfmFile:
    """``afm`` with every channel's rows in the opposite order (``metadata["lines_reversed"] = True``).

    For a file whose rows are stored last-scanned first although its reader cannot tell (a ``.gwy``
    that an import flipped for display: Gwyddion's ``nanonis`` module reverses an upward frame, and
    a ``.gwy`` keeps no slow-scan direction). Row 0 becomes the first line scanned, as
    :class:`Channel` promises; the image is mirrored along y (afmsim scans its slow axis upwards).
    Columns, sizes, line times and offsets are unchanged."""
    channels = tuple(replace(c, data=np.ascontiguousarray(c.data[::-1])) for c in afm.channels)
    return replace(afm, channels=channels, metadata={**afm.metadata, "lines_reversed": True})


# --- units -----------------------------------------------------------------------------------

_PREFIX = {"": 1.0, "k": 1e3, "m": 1e-3, "u": 1e-6, "µ": 1e-6, "μ": 1e-6, "~": 1e-6, "n": 1e-9, "p": 1e-12,
           "f": 1e-15}
_BASE = {"m": "m", "V": "V", "A": "A", "N": "N", "Hz": "Hz", "s": "s", "W": "W", "rad": "rad"}
_DEGREE = {"deg", "°", "Â°", "degree", "degrees", "º"}


def to_si(unit: str) -> tuple[str, float]:
    """``(si_unit, factor)`` so that ``value_in_unit · factor`` is in ``si_unit``.

    Knows the prefixes k, m, µ/u/~ (Nanoscope writes ``~m``), n, p, f on m, V, A, N, Hz, s, W;
    Ångström; degrees in their usual spellings. An unknown unit comes back unchanged (factor 1).
    """
    text = (unit or "").strip()
    if text in _DEGREE:
        return "deg", 1.0
    if text in ("Å", "A°", "Angstrom"):
        return "m", 1e-10
    if text in _BASE:
        return text, 1.0
    if len(text) >= 2 and text[0] in _PREFIX and text[1:] in _BASE:
        return _BASE[text[1:]], _PREFIX[text[0]]
    return text, 1.0


def leading_number(text) -> float | None:
    """The number a header value starts with (``"-45 °"`` → -45.0), or None."""
    match = re.match(r"\s*([-+]?[0-9.]+(?:[eE][-+]?\d+)?)", str(text or ""))
    try:
        return float(match.group(1)) if match else None
    except ValueError:
        return None


# --- names ---------------------------------------------------------------------------------------

# Checked in this order: the first rule whose pattern is found in the lower-cased name wins.
_QUANTITY_RULES = (
    ("lateral", r"friction|lateral|torsion|\blfm\b"),
    ("phase", r"phase"),
    ("amplitude", r"amplitude|\bamp\b|\bmag"),
    ("deflection", r"deflection|\bdefl|\berror\b|\bforce\b|\bdfl\b|setpoint"),
    ("current", r"current"),
    ("height", r"topo|height|z[-_ ]?axis|z[-_ ]?sensor|z[-_ ]?piezo|^z\b|^z[-_ ]|\bzsens"),
)
_DIRECTION_WORDS = (  # (pattern, direction); retrace before trace, backward before forward
    (r"re[-_ ]?trace", "retrace"), (r"trace", "trace"),
    (r"backward|\bbwd\b|\bback\b|\bbw\b", "backward"), (r"forward|\bfwd\b|\bfw\b", "forward"),
)


def quantity_of(name: str, unit: str) -> str:
    """The physical quantity a channel records, from its name and SI unit.

    A length channel (unit ``m``) whose name says nothing else is taken as a height.
    """
    low = name.lower()
    for quantity, pattern in _QUANTITY_RULES:
        if re.search(pattern, low):
            return quantity
    return "height" if unit == "m" else "other"


def split_direction(title: str) -> tuple[str, str]:
    """``(name, direction)`` from a channel title that carries the direction as a word.

    ``"Z-Axis forward"`` → ``("Z-Axis", "forward")``; ``"HeightRetrace"`` → ``("Height", "retrace")``;
    ``"Topography [Bwd]"`` → ``("Topography", "backward")``; ``"trace none"`` → ``("none", "trace")``.
    A title without such a word comes back with direction ``""``.
    """
    for pattern, direction in _DIRECTION_WORDS:
        match = re.search(pattern, title, flags=re.IGNORECASE)
        if match:
            name = (title[:match.start()] + " " + title[match.end():])
            name = re.sub(r"[\[\(]\s*[\]\)]", " ", name)  # brackets left empty by the removal
            name = re.sub(r"\s+", " ", name).strip(" -_:,")
            return name or title.strip(), direction
    return title.strip(), ""


def scanned_lines(*images: np.ndarray, min_lines: int = 1) -> int:
    """How many lines (rows in scan order) of a frame were scanned: trailing lines that hold a run of two
    or more non-finite pixels, or one value throughout (a fill), in any of ``images`` are a frame
    stopped before its end. All lines when fewer than ``min_lines`` would remain (the caller's own
    checks then say what is wrong)."""
    def unscanned(line: np.ndarray) -> bool:
        bad = ~np.isfinite(line)
        return bool(np.any(bad[1:] & bad[:-1])) or bool(bad.all()) or np.ptp(line[~bad]) == 0

    total = images[0].shape[0]
    n = total
    while n > 0 and any(unscanned(np.asarray(image[n - 1], dtype=float)) for image in images):
        n -= 1
    return n if n >= min_lines else total
