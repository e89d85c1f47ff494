"""Reading and validating measured trace/retrace images (``.npz``, ``.gwy``, vendor files, or arrays).

Accepted inputs (heights in metres, rows = scan lines along +y, columns = pixels left → right in
*both* images, i.e. the retrace already re-ordered to intended x); a file is read once, by
:func:`afmsim.readers.read_afm_file` (one reader per format):

* ``.npz`` with ``trace``, ``retrace`` (2-D), ``scan_size_m`` (x, y) and ``line_rate_hz``;
  optional ``scan_offset_m`` (stage position of the scan window's lower-left corner);
* ``images.npz`` written by ``afmsim run``: ``trace_<controller>``/``retrace_<controller>`` with
  ``image_pixel_size_m``/``image_origin_m`` (scan size and offset follow); the line rate comes from
  the ``scenario.yaml`` beside it, or from the ``line_rate_hz`` argument (``--scenario``);
* Gwyddion ``.gwy`` with channels titled ``trace``/``retrace`` (or ``trace <c>``/``retrace <c>``, as
  ``afmsim run`` writes them); scan size and offset from the channel geometry, the line rate from
  the ``line_rate_hz`` argument, else from the channels' metadata (the ``line rate (Hz)`` a run writes);
* an instrument file that :mod:`afmsim.readers` reads (Nanosurf ``.nid``, Asylum ``.ibw``, Bruker
  ``.spm``/``.000``–``.999``, or a ``.gwy`` without trace/retrace titles): the height channel's
  forward/backward scans as :func:`afmsim.readers.pick_height_pair` picks them (``channel``
  overrides), scan size from the file, line rate ``1 / (2 · line_time_s)`` from the file (else the
  ``line_rate_hz`` argument); rows in the order they were scanned (a top-down frame's rows
  reversed); no scan offset (the vendors' offsets are not stage coordinates);
* a mapping with the ``.npz`` keys, and optionally ``error_trace``/``error_retrace`` (the Z loop's
  error signal, same shape) with ``error_channel`` (its name).

An instrument file's error signal (amplitude, deflection or a channel named an error) comes with
its heights where the file has it in both directions (:func:`afmsim.readers.pick_error_pair`).

Large images are cut down before a diagnosis (:func:`within_budget`): at most :data:`MAX_LINES`
lines (the first ones scanned) and :data:`MAX_PIXELS` pixels per line (block means of neighbouring
pixels). The diagnosis simulates every sample of the frame: 256 × 256 takes 45 s and 2.5 GB,
256 × 512 110 s and 4.3 GB, 512 × 512 took 8.5 min and 8.5 GB (2-CPU machine), so a 1,024 × 1,024
file would not finish.

Every problem raises :class:`ValueError` with one line naming the field. A frame stopped before its
end (the last lines NaN, cut short by a NaN run, or one constant fill value, as instruments store
lines never scanned) is diagnosed on the lines it scanned, the scan height cut in proportion
(``ImageRecord.unscanned_lines``). Isolated non-finite pixels (no neighbour along the line also
bad) are filled by linear interpolation along the line; runs of two or more elsewhere, or a bad
first/last pixel, are refused.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from afmsim.readers.channels import scanned_lines

__all__ = ["ImageRecord", "load_images", "within_budget", "MIN_LINES", "MIN_PIXELS", "MAX_LINES", "MAX_PIXELS"]

MIN_LINES = 16
MIN_PIXELS = 16
#: Largest image a diagnosis works on (:func:`within_budget`): 256 lines, the size of the real files
#: it was developed on, of up to 512 pixels (a 256 × 512 real file: 110 s, 4.3 GB). Lines are cut
#: before pixels are averaged: averaging changes the pixel scale at which the noise floor is
#: estimated (second differences), cutting lines does not.
MAX_LINES = 256
MAX_PIXELS = 512
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
    picked : str or None
        For an instrument file, the one line saying which channel pair was picked and why
        (:func:`afmsim.readers.pick_height_pair`); None otherwise.
    error_trace, error_retrace : ndarray (lines, pixels) or None
        The Z loop's error signal in each direction, on the height's grid (an instrument file's
        amplitude / deflection / error channel, :func:`afmsim.readers.pick_error_pair`; the
        ``.npz`` keys of the same names); non-finite pixels are left as they are. None when absent.
    error_channel : str or None
        Its name and unit (``"Amplitude (V)"``).
    unscanned_lines : int
        Lines at the end of the file's frame that were never scanned (a scan stopped early: NaN or
        a constant fill), dropped with their share of the scan height.
    """

    trace: np.ndarray
    retrace: np.ndarray
    scan_size_m: tuple[float, float]
    line_rate_hz: float
    scan_offset_m: tuple[float, float] | None = None
    source: str = "arrays"
    filled_pixels: int = 0
    picked: str | None = None
    error_trace: np.ndarray | None = field(default=None, repr=False)
    error_retrace: np.ndarray | None = field(default=None, repr=False)
    error_channel: str | None = None
    unscanned_lines: int = 0

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


def _validate(cols: dict, source: str, picked: str | None = None) -> ImageRecord:
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
        shown = [float(f"{v:.12g}") for v in rate.tolist()]  # a rate read back from a line time, unrounded
        raise ValueError(f"line_rate_hz must be one number in (0, 10000] Hz, got {shown}")
    offset = _pair("scan_offset_m", cols["scan_offset_m"]) if cols.get("scan_offset_m") is not None else None
    errors = _error_pair(cols, trace.shape)
    scanned = scanned_lines(trace, retrace, min_lines=MIN_LINES)
    if scanned < ny:  # a frame stopped early: the lines never scanned go, the scan height with them
        trace, retrace = trace[:scanned], retrace[:scanned]
        errors = tuple(e[:scanned] if isinstance(e, np.ndarray) else e for e in errors)
        size = (size[0], size[1] * scanned / ny)
    trace, n_t = _fill_isolated("trace", trace)
    retrace, n_r = _fill_isolated("retrace", retrace)
    if np.ptp(trace) == 0 or np.ptp(retrace) == 0:
        raise ValueError("trace or retrace is flat: there is no topography to diagnose")
    return ImageRecord(trace, retrace, size, float(rate[0]), offset, source, n_t + n_r, picked, *errors,
                       unscanned_lines=ny - scanned)


def _error_pair(cols: dict, shape: tuple[int, int]) -> tuple:
    """``(error_trace, error_retrace, error_channel)`` from the columns (all None when absent)."""
    given = [k for k in ("error_trace", "error_retrace") if cols.get(k) is not None]
    if not given:
        return None, None, None
    if len(given) == 1:
        raise ValueError(f"{given[0]} given without {({'error_trace', 'error_retrace'} - set(given)).pop()}: "
                         "the error signal needs both scan directions")
    pair = tuple(np.asarray(cols[k], dtype=np.float64) for k in ("error_trace", "error_retrace"))
    for key, image in zip(("error_trace", "error_retrace"), pair):
        if image.shape != shape:
            raise ValueError(f"{key} must have the heights' shape {shape}, got {image.shape}")
    return (*pair, str(cols.get("error_channel") or "error signal"))


def _own_pair(afm, channel: str | None) -> tuple:
    """``(trace, retrace, controller)`` of afmsim's own images: the plain pair (channel ``height``;
    controller None, ``channel`` ignored), else the controller ``channel`` (default ``none``, else
    the first by name)."""
    pairs: dict[str, dict] = {}
    for c in afm.channels:
        if c.direction in ("trace", "retrace") and c.quantity == "height":
            pairs.setdefault(c.name, {})[c.direction] = c
    label = afm.path.name
    if "height" in pairs:
        name, pair = None, pairs["height"]
    else:
        found = sorted(pairs)
        if channel is not None and channel not in found:
            raise ValueError(f"{label}: no channel 'trace_{channel}'; available controllers: {found}")
        if not found:
            raise ValueError(f"{label}: lacks key(s) ['trace', 'retrace'] (or trace_<controller>/retrace_<controller>)")
        name = channel if channel is not None else "none" if "none" in found else found[0]
        pair = pairs[name]
    for direction in ("trace", "retrace"):
        if direction not in pair:
            raise ValueError(f"{label}: channel '{direction}{'' if name is None else ' ' + name}' missing")
    return pair["trace"], pair["retrace"], name


def _own_error_pair(afm, trace) -> tuple | None:
    """The error signal beside afmsim's own height pair: a run's ``error_trace_<controller>`` pair
    (``images.npz``: deflection channels of the controller's name; ``images.gwy``: "error trace <c>",
    read as "error <c>"), a plain ``.npz``'s ``error_trace``/``error_retrace``."""
    names = ("error",) if trace.name == "height" else (trace.name, f"error {trace.name}")
    pair = {c.direction: c for c in afm.channels if c.quantity == "deflection" and c.name in names
            and c.shape == trace.shape}
    return (pair["trace"], pair["retrace"]) if {"trace", "retrace"} <= set(pair) else None


def _columns(afm, channel: str | None, line_rate_hz: float | None) -> tuple[dict, str | None, str | None]:
    """``(columns, picked, label)``: the :func:`_validate` columns of a file read by
    :mod:`afmsim.readers`, the one-line description of the vendor channel picked (None for
    afmsim's own images) and the channel named in the record's source (None for a plain pair).

    Line rate: an instrument file's or a plain ``.npz``'s own first, then ``line_rate_hz``; for a
    run's ``images.npz``/``images.gwy`` ``line_rate_hz`` first, then what the run recorded.
    """
    from afmsim.readers import pick_error_pair, pick_height_pair

    own = afm.format == "npz" or (afm.format == "gwy" and any(c.direction in ("trace", "retrace")
                                                              for c in afm.channels))
    if own:
        trace, retrace, label = _own_pair(afm, channel)
        picked, file_first, offset = None, afm.format == "npz" and label is None, trace.offset_m
    else:  # a vendor's offsets are not stage coordinates
        trace, retrace, picked = pick_height_pair(afm, channel)
        label, file_first, offset = f"{trace.name} {trace.direction}/{retrace.direction}", True, None
    recorded = 1.0 / (2.0 * trace.line_time_s) if trace.line_time_s else None
    rate = (recorded or line_rate_hz) if file_first else (line_rate_hz or recorded)
    if rate is None:
        beside = " and no readable scenario.yaml beside it" if afm.format == "npz" and label is not None else ""
        raise ValueError(f"{afm.path.name}: line rate unknown (the file records no line time{beside}); "
                         "give --scenario (scan.line_rate_hz)")
    cols = {"trace": trace.data, "retrace": retrace.data, "scan_size_m": trace.size_m, "line_rate_hz": rate,
            "scan_offset_m": offset}
    error = _own_error_pair(afm, trace) if own else pick_error_pair(afm, trace.shape)
    if error is not None:
        cols.update(error_trace=error[0].data, error_retrace=error[1].data,
                    error_channel="deflection error (m)" if own else f"{error[0].name} ({error[0].unit or 'no unit'})")
    return cols, picked, label


def within_budget(record: ImageRecord) -> tuple[ImageRecord, dict | None]:
    """``record`` cut to at most :data:`MAX_LINES` × :data:`MAX_PIXELS`, and what was done (None: nothing).

    Lines: the first :data:`MAX_LINES` scanned, the scan height cut in proportion; they keep the
    frame's start, the slow axis's path from rest and every line's timing, so the model of the cut
    frame is the model of the instrument's first lines. Pixels: block means of ``k`` neighbours
    (``k = ⌈pixels / MAX_PIXELS⌉``) along each line, trace and retrace alike; the line time, hence
    the fast axis's speed, stays as recorded. Pixels beyond the last whole block (fewer than ``k``)
    are dropped from the right end and the scan width with them. Averaged pixels are coarser: the
    noise floor, estimated from second differences along the line, then also sees more of the
    sample's own curvature (``MoS2.nid``, 512 pixels averaged in pairs: floor 0.048 → 0.09 nm, the
    gap 8.3× → 4.2× the floor), which :func:`budget_text` says.
    """
    ny, nx = record.shape
    if ny <= MAX_LINES and nx <= MAX_PIXELS:
        return record, None
    lines = min(ny, MAX_LINES)
    k = -(-nx // MAX_PIXELS)
    kept = nx - nx % k

    def cut(image: np.ndarray) -> np.ndarray:
        return image[:lines, :kept].reshape(lines, kept // k, k).mean(axis=2)

    size = (record.scan_size_m[0] * kept / nx, record.scan_size_m[1] * lines / ny)
    done = {"lines_used": lines, "of_lines": ny, "pixels_per_bin": k, "pixels_used": kept, "of_pixels": nx,
            "scan_size_m": list(size)}
    errors = {} if record.error_trace is None else \
        {"error_trace": cut(record.error_trace), "error_retrace": cut(record.error_retrace)}
    return replace(record, trace=cut(record.trace), retrace=cut(record.retrace), scan_size_m=size, **errors), done


def budget_text(done: dict) -> str:
    """One line on how :func:`within_budget` cut an image."""
    parts = []
    if done["lines_used"] < done["of_lines"]:
        parts.append(f"the first {done['lines_used']} of {done['of_lines']} lines")
    if done["pixels_per_bin"] > 1:
        dropped = done["of_pixels"] - done["pixels_used"]
        parts.append(f"pixels averaged in blocks of {done['pixels_per_bin']} ({done['of_pixels']} → "
                     f"{done['pixels_used'] // done['pixels_per_bin']} per line"
                     + (f", the last {dropped} dropped" if dropped else "") + ")")
    text = (f"Image cut to the diagnosis's {MAX_LINES} lines × {MAX_PIXELS} pixels: " + "; ".join(parts)
            + f"; scan window {done['scan_size_m'][0] * 1e6:.3g} × {done['scan_size_m'][1] * 1e6:.3g} µm.")
    if done["pixels_per_bin"] > 1:
        text += (" The noise floor is estimated on the averaged pixels and can read higher than at the file's "
                 "own pixel size (the sample's curvature counts more): a gap near 2× the floor is not proof "
                 "that nothing is missing.")
    return text


def load_images(source, *, channel: str | None = None, line_rate_hz: float | None = None,
                retrace=None, reverse_lines: bool = False) -> ImageRecord:
    """Validated :class:`ImageRecord` from a ``.npz``/``.gwy``/instrument-file path (read once, by
    :func:`afmsim.readers.read_afm_file`) or a mapping with the ``.npz`` keys; an
    :class:`ImageRecord` comes back as it is (already read and validated).

    ``channel`` picks the controller of a run's ``images.npz``/``images.gwy`` (default ``none``), or
    the vendor channel of an instrument file (default: the topography, see
    :func:`afmsim.readers.pick_height_pair`). ``line_rate_hz`` (Hz, the scenario's) is used where an
    instrument file or a plain ``.npz`` records none, and before what a run's ``images.npz``/
    ``images.gwy`` recorded. ``retrace``: a second instrument file holding the other scan direction
    (Park Systems writes one direction per file), read with ``source`` as one file
    (:func:`afmsim.readers.read_afm_files`). ``reverse_lines``: the file stores its lines
    last-scanned first although its reader cannot tell (a ``.gwy`` flipped by an import); every
    channel's rows are reversed before anything else (:func:`afmsim.readers.reversed_lines`), so the
    first line scanned comes first — read backwards in time, a stage's slow-axis creep and drift
    fit no model (docs/diagnosis.md, "Line order matters"). A path or a mapping only.
    """
    if retrace is not None and not isinstance(source, (str, Path)):
        raise ValueError("retrace: a second file goes with an image file path only")
    if isinstance(source, ImageRecord):
        if reverse_lines:
            raise ValueError("reverse_lines: give the file or the arrays, not a record already read")
        return source
    if isinstance(source, (str, Path)):
        from afmsim.readers import FORMATS, read_afm_files, reader_for, reversed_lines

        path = Path(source)
        if not path.is_file():
            raise ValueError(f"image file not found: {path}")
        if reader_for(path) is None:
            raise ValueError(f"image file must be .npz or .gwy (images) or an instrument file ({FORMATS}), "
                             f"got {path.name}")
        files = (path,) if retrace is None else (path, Path(retrace))  # an unknown suffix: the reader's one line
        afm = read_afm_files(*files)
        cols, picked, channel_label = _columns(reversed_lines(afm) if reverse_lines else afm, channel, line_rate_hz)
        label = " + ".join([str(path), *(f.name for f in files[1:])]) + (" (lines reversed)" if reverse_lines else "")
        return _validate(cols, label + (f" [{channel_label}]" if channel_label else ""), picked)
    if isinstance(source, dict):
        missing = [k for k in REQUIRED if k not in source and not (k == "line_rate_hz" and line_rate_hz)]
        if missing:
            raise ValueError(f"images lack key(s) {missing}; need trace, retrace, scan_size_m, line_rate_hz")
        cols = dict(source)
        cols.setdefault("line_rate_hz", line_rate_hz)
        if reverse_lines:
            cols.update({k: np.asarray(cols[k])[::-1] for k in ("trace", "retrace", "error_trace", "error_retrace")
                         if cols.get(k) is not None})
        return _validate(cols, "arrays (lines reversed)" if reverse_lines else "arrays")
    raise ValueError("images must be a .npz/.gwy path or a dict with trace, retrace, scan_size_m, line_rate_hz")
