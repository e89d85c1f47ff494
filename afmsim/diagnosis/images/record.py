"""Reading and validating measured trace/retrace images (``.npz``, ``.gwy``, vendor files, or arrays).

Accepted inputs (heights in metres, rows = scan lines along +y, columns = pixels left → right in
*both* images, i.e. the retrace already re-ordered to intended x):

* ``.npz`` with ``trace``, ``retrace`` (2-D), ``scan_size_m`` (x, y) and ``line_rate_hz``;
  optional ``scan_offset_m`` (stage position of the scan window's lower-left corner);
* ``images.npz`` written by ``afmsim run``: ``trace_<controller>``/``retrace_<controller>`` with
  ``image_pixel_size_m``/``image_origin_m`` (scan size and offset follow); the line rate comes from
  the ``scenario.yaml`` beside it, or from the ``line_rate_hz`` argument (``--scenario``);
* Gwyddion ``.gwy`` with channels titled ``trace``/``retrace`` (or ``trace <c>``/``retrace <c>``, as
  ``afmsim run`` writes them); scan size and offset from the channel geometry, the line rate from
  the ``line_rate_hz`` argument;
* an instrument file that :mod:`afmsim.readers` reads (Nanosurf ``.nid``, Asylum ``.ibw``, Bruker
  ``.spm``/``.000``–``.999``, or a ``.gwy`` without trace/retrace titles): the height channel's
  forward/backward scans as :func:`afmsim.readers.pick_height_pair` picks them (``channel``
  overrides), scan size from the file, line rate ``1 / (2 · line_time_s)`` from the file (else the
  ``line_rate_hz`` argument); rows in the order they were scanned (a top-down frame's rows
  reversed); no scan offset (the vendors' offsets are not stage coordinates);
* a mapping with the ``.npz`` keys.

Every problem raises :class:`ValueError` with one line naming the field. Isolated non-finite
pixels (no neighbour along the line also bad) are filled by linear interpolation along the line;
runs of two or more, or a bad first/last pixel, are refused.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ImageRecord", "load_images", "instrument_pair", "MIN_LINES", "MIN_PIXELS"]

MIN_LINES = 16
MIN_PIXELS = 16
REQUIRED = ("trace", "retrace", "scan_size_m", "line_rate_hz")


@dataclass(frozen=True)
class ImageRecord:
    """A validated trace/retrace pair (SI units).

    Attributes
    ----------
    trace, retrace : ndarray (lines, pixels)
        Recorded heights, m, both left → right.
    scan_size_m : (float, float)
        Scan window width (x, fast axis) and height (y, slow axis), m.
    line_rate_hz : float
        Lines per second (one line = trace + retrace).
    scan_offset_m : (float, float) or None
        Stage position of the window's lower-left corner, m, when the file gives it.
    source : str
        Where the images came from (path and channel).
    filled_pixels : int
        Isolated non-finite pixels filled by interpolation.
    """

    trace: np.ndarray
    retrace: np.ndarray
    scan_size_m: tuple[float, float]
    line_rate_hz: float
    scan_offset_m: tuple[float, float] | None = None
    source: str = "arrays"
    filled_pixels: int = 0

    @property
    def shape(self) -> tuple[int, int]:
        """(lines, pixels)."""
        return self.trace.shape

    @property
    def pixel_size_m(self) -> tuple[float, float]:
        """(dx, dy), m."""
        return (self.scan_size_m[0] / self.shape[1], self.scan_size_m[1] / self.shape[0])


def _fill_isolated(name: str, a: np.ndarray) -> tuple[np.ndarray, int]:
    bad = ~np.isfinite(a)
    if not bad.any():
        return a, 0
    rows = np.nonzero(bad.all(axis=1))[0]
    if rows.size:
        raise ValueError(f"{name}: line {int(rows[0])} has no finite pixel (whole-line NaN); crop the image")
    run = bad[:, 1:] & bad[:, :-1]
    edge = bad[:, 0] | bad[:, -1]
    if run.any() or edge.any():
        line = int(np.nonzero(run.any(axis=1) | edge)[0][0])
        raise ValueError(f"{name}: line {line} has a run of NaN/inf pixels (or one at a line end); "
                         "crop or fill the gap")
    out = a.copy()
    cols = np.arange(a.shape[1])
    for k in np.nonzero(bad.any(axis=1))[0]:
        m = bad[k]
        out[k, m] = np.interp(cols[m], cols[~m], a[k, ~m])
    return out, int(bad.sum())


def _pair(name: str, value, length: int = 2) -> tuple[float, ...]:
    a = np.asarray(value, dtype=np.float64).ravel()
    if a.size != length or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be {length} finite numbers (m), got {a.tolist()}")
    return tuple(float(v) for v in a)


def _validate(cols: dict, source: str) -> ImageRecord:
    trace = np.asarray(cols["trace"], dtype=np.float64)
    retrace = np.asarray(cols["retrace"], dtype=np.float64)
    if trace.ndim != 2 or retrace.ndim != 2:
        raise ValueError(f"trace and retrace must be 2-D (lines × pixels), got shapes {trace.shape} and {retrace.shape}")
    if trace.shape != retrace.shape:
        raise ValueError(f"trace and retrace shapes differ: {trace.shape} vs {retrace.shape}")
    ny, nx = trace.shape
    if ny < MIN_LINES or nx < MIN_PIXELS:
        raise ValueError(f"images too small: {ny} lines × {nx} pixels, need at least {MIN_LINES} lines and "
                         f"{MIN_PIXELS} pixels")
    size = _pair("scan_size_m", cols["scan_size_m"])
    if min(size) <= 0 or max(size) > 1e-3:
        raise ValueError(f"scan_size_m must be in (0, 1e-3] m on both axes, got {list(size)}")
    rate = np.asarray(cols["line_rate_hz"], dtype=np.float64).ravel()
    if rate.size != 1 or not np.isfinite(rate[0]) or not 0 < rate[0] <= 1e4:
        raise ValueError(f"line_rate_hz must be one number in (0, 10000] Hz, got {rate.tolist()}")
    offset = _pair("scan_offset_m", cols["scan_offset_m"]) if cols.get("scan_offset_m") is not None else None
    trace, n_t = _fill_isolated("trace", trace)
    retrace, n_r = _fill_isolated("retrace", retrace)
    if np.ptp(trace) == 0 or np.ptp(retrace) == 0:
        raise ValueError("trace or retrace is flat: there is no topography to diagnose")
    return ImageRecord(trace, retrace, size, float(rate[0]), offset, source, n_t + n_r)


def _pick(names, prefix: str, channel: str | None, source: str) -> str:
    found = sorted(n[len(prefix):] for n in names if n.startswith(prefix))
    if channel is not None:
        if channel not in found:
            raise ValueError(f"{source}: no channel '{prefix}{channel}'; available controllers: {found}")
        return channel
    if not found:
        raise ValueError(f"{source}: lacks key(s) ['trace', 'retrace'] (or trace_<controller>/retrace_<controller>)")
    return "none" if "none" in found else found[0]


def _scenario_line_rate(path: Path) -> float | None:
    beside = path.parent / "scenario.yaml"
    if not beside.is_file():
        return None
    from afmsim.scenario import ScenarioError, load_scenario

    try:
        return float(load_scenario(beside).scan.line_rate_hz)
    except ScenarioError as error:
        raise ValueError(f"{beside}: {error}") from None


def _read_npz(path: Path, channel, line_rate_hz) -> dict:
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise ValueError(f"{path.name} is not a readable .npz file ({(str(error).splitlines() or [''])[0]})") from None
    if "trace" in arrays or "retrace" in arrays:
        missing = [k for k in REQUIRED if k not in arrays and not (k == "line_rate_hz" and line_rate_hz)]
        if missing:
            raise ValueError(f"{path.name} lacks key(s) {missing}; need trace, retrace, scan_size_m, line_rate_hz")
        cols = {k: arrays[k] for k in (*REQUIRED, "scan_offset_m") if k in arrays}
        cols.setdefault("line_rate_hz", line_rate_hz)
        return cols
    name = _pick(arrays, "trace_", channel, path.name)
    if f"retrace_{name}" not in arrays or "image_pixel_size_m" not in arrays or "image_origin_m" not in arrays:
        raise ValueError(f"{path.name} lacks key(s) retrace_{name}, image_pixel_size_m or image_origin_m")
    trace = arrays[f"trace_{name}"]
    pixel = _pair("image_pixel_size_m", arrays["image_pixel_size_m"])
    origin = _pair("image_origin_m", arrays["image_origin_m"])
    rate = line_rate_hz if line_rate_hz is not None else _scenario_line_rate(path)
    if rate is None:
        raise ValueError(f"{path.name}: line rate unknown (no scenario.yaml beside it); give --scenario")
    ny, nx = np.shape(trace) if np.ndim(trace) == 2 else (1, 1)
    return {"trace": trace, "retrace": arrays[f"retrace_{name}"], "line_rate_hz": rate,
            "scan_size_m": (pixel[0] * nx, pixel[1] * ny),
            "scan_offset_m": (origin[0] - pixel[0] / 2, origin[1] - pixel[1] / 2), "_channel": name}


def _gwy_line_rate(path: Path) -> float | None:
    """Line rate (Hz, one line = trace + retrace) from the channels' metadata (:mod:`afmsim.readers.gwy`:
    an import's ``Time/Line``/``Scan rate``, or the ``line rate (Hz)`` afmsim writes), when all agree."""
    from afmsim.readers import ReaderError, read_afm_file

    try:
        times = {c.line_time_s for c in read_afm_file(path).channels if c.line_time_s}
    except ReaderError:
        return None
    return 1.0 / (2.0 * times.pop()) if len(times) == 1 else None


def _read_gwy(path: Path, channel, line_rate_hz) -> dict:
    from afmsim.report.gwy import read_gwy

    try:
        maps = read_gwy(path)
    except Exception as error:  # gwyfile raises several exception types on a corrupt file
        raise ValueError(f"{path.name} is not a readable .gwy file ({str(error).splitlines()[0]})") from None
    titles = {t.strip().lower(): t for t in maps}
    if "trace" in titles and "retrace" in titles:
        t, r = maps[titles["trace"]], maps[titles["retrace"]]
        name = None
    else:
        name = _pick([k.replace(" ", "_", 1) for k in titles], "trace_", channel, path.name)
        if f"retrace {name}" not in titles:
            raise ValueError(f"{path.name}: channel 'retrace {name}' missing")
        t, r = maps[titles[f"trace {name}"]], maps[titles[f"retrace {name}"]]
    if line_rate_hz is None:
        line_rate_hz = _gwy_line_rate(path)
    if line_rate_hz is None:
        raise ValueError(f"{path.name}: the .gwy file records no line rate; give --scenario (scan.line_rate_hz)")
    dx, dy = t.pixel_size
    return {"trace": t.z, "retrace": r.z, "scan_size_m": t.size, "line_rate_hz": line_rate_hz,
            "scan_offset_m": (t.origin[0] - dx / 2, t.origin[1] - dy / 2), "_channel": name}


def instrument_pair(path, channel: str | None = None):
    """``(trace, retrace, picked)`` channels of an instrument file, or None for afmsim's own images.

    None for a ``.npz`` and for a ``.gwy`` titled ``trace``/``retrace`` (as ``afmsim run`` writes);
    otherwise the pair :func:`afmsim.readers.pick_height_pair` picks, with its one-line description.
    Raises :class:`afmsim.readers.ReaderError` (a ``ValueError``) for an unreadable file.
    """
    from afmsim.readers import pick_height_pair, read_afm_file

    path = Path(path)
    if path.suffix.lower() == ".npz":
        return None
    afm = read_afm_file(path)
    if afm.format == "gwy" and any(c.direction in ("trace", "retrace") for c in afm.channels):
        return None
    return pick_height_pair(afm, channel)


def _read_instrument(path: Path, pair, line_rate_hz) -> dict:
    trace, retrace, _ = pair
    rate = 1.0 / (2.0 * trace.line_time_s) if trace.line_time_s else line_rate_hz
    if rate is None:
        raise ValueError(f"{path.name}: the file gives no line time; give --scenario (scan.line_rate_hz)")
    return {"trace": trace.data, "retrace": retrace.data, "scan_size_m": trace.size_m, "line_rate_hz": rate,
            "_channel": f"{trace.name} {trace.direction}/{retrace.direction}"}


def load_images(source, *, channel: str | None = None, line_rate_hz: float | None = None) -> ImageRecord:
    """Validated :class:`ImageRecord` from a ``.npz``/``.gwy``/instrument-file path or a mapping with
    the ``.npz`` keys.

    ``channel`` picks the controller of a run's ``images.npz``/``images.gwy`` (default ``none``), or
    the vendor channel of an instrument file (default: the topography, see
    :func:`afmsim.readers.pick_height_pair`); ``line_rate_hz`` (Hz) is used where the file has none.
    """
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.is_file():
            raise ValueError(f"image file not found: {path}")
        from afmsim.readers import FORMATS, reader_for

        suffix = path.suffix.lower()
        pair = instrument_pair(path, channel) if reader_for(path) is not None else None
        if pair is not None:
            cols = _read_instrument(path, pair, line_rate_hz)
        elif suffix == ".npz":
            cols = _read_npz(path, channel, line_rate_hz)
        elif suffix == ".gwy":
            cols = _read_gwy(path, channel, line_rate_hz)
        else:
            raise ValueError(f"image file must be .npz or .gwy (images) or an instrument file ({FORMATS}), "
                             f"got {path.name}")
        label = str(path) + (f" [{cols['_channel']}]" if cols.get("_channel") else "")
    elif isinstance(source, dict):
        missing = [k for k in REQUIRED if k not in source and not (k == "line_rate_hz" and line_rate_hz)]
        if missing:
            raise ValueError(f"images lack key(s) {missing}; need trace, retrace, scan_size_m, line_rate_hz")
        cols = dict(source)
        cols.setdefault("line_rate_hz", line_rate_hz)
        label = "arrays"
    else:
        raise ValueError("images must be a .npz/.gwy path or a dict with trace, retrace, scan_size_m, line_rate_hz")
    return _validate(cols, label)
