"""Nanonis ``.sxm`` scan files (SPECS Nanonis controllers), read with ``pySPM``'s ``SXM`` class.

An ``.sxm`` file is an ASCII header of ``:TAG:`` lines and their values, closed by ``:SCANIT_END:``,
then the bytes ``\\x1a\\x04`` and the images: for each channel of the ``:DATA_INFO:`` table, in its
order, the forward image and then (direction ``both``) the backward one, ``SCAN_PIXELS`` (pixels
per line, lines) values each, 32-bit floats in the byte order ``SCANIT_TYPE`` names, in the
channel's unit (``Z`` in m, ``Current`` in A, ``Amplitude`` in V, ``Phase`` in deg…).

``pySPM`` parses the header and cuts each image out of the data block; this module checks the file
before handing it over (``pySPM`` reads line after line forever on a file without
``:SCANIT_END:`` or without the ``\\x1a\\x04`` marker, and past the end of a cut one) and adds what
``pySPM`` leaves out:

* rows: the file stores the lines in the order they were scanned, for an upward and a downward
  slow scan alike (Gwyddion turns an ``up`` frame over for display, a ``down`` one not), so they are
  kept; ``SCAN_DIR`` is reported in the metadata;
* columns: a backward image is stored as acquired, right → left, and is reversed (as Gwyddion
  does), so both directions run left → right;
* line time: ``SCAN_TIME`` gives the forward and the backward line's duration (s) separately;
  each channel takes its own direction's;
* size: ``SCAN_RANGE`` (m, x then y); ``SCAN_ANGLE`` (deg) is reported as the scan rotation;
* a frame stopped before its end holds NaN in the lines never scanned (dropped downstream with
  their share of the scan height, :func:`afmsim.readers.scanned_lines`).

Only ``FLOAT`` data are read (``pySPM`` reads four bytes a value whatever the type; Nanonis writes
floats); another ``SCANIT_TYPE`` gets one line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .channels import AfmFile, Channel, ReaderError, leading_number, quantity_of, to_si

__all__ = ["read_sxm"]

_MAGIC = b":NANONIS_VERSION:"
_END = b":SCANIT_END:"
_DATA_MARK = b"\x1a\x04"
_DIRECTIONS = {"both": ("forward", "backward"), "forward": ("forward",), "backward": ("backward",)}


def _value(header: dict, key: str) -> list[str]:
    """The words of a header tag's first value line (``[]`` when the tag is missing or empty)."""
    lines = header.get(key) or [[]]
    return list(lines[0])


def read_sxm(path: Path) -> AfmFile:
    """Every image of a Nanonis ``.sxm`` file (see the module notes for the conventions)."""
    import pySPM

    raw = path.read_bytes()
    if not raw.startswith(_MAGIC):
        raise ReaderError(f"{path.name}: not a Nanonis scan file (no :NANONIS_VERSION: header)")
    end = raw.find(_END)
    mark = raw.find(_DATA_MARK, end) if end >= 0 else -1
    if end < 0 or mark < 0:
        raise ReaderError(f"{path.name}: truncated Nanonis file (no {':SCANIT_END:' if end < 0 else 'data marker'} "
                          "after the header)")
    try:
        scan = pySPM.SXM(str(path))
        kind = _value(scan.header, "SCANIT_TYPE")
        nx, ny = (int(v) for v in _value(scan.header, "SCAN_PIXELS")[:2])
        width, height = (float(v) for v in _value(scan.header, "SCAN_RANGE")[:2])
        table = scan.header["DATA_INFO"]
        columns = table[0]
        infos = [dict(zip(columns, row)) for row in table[1:]]
    except (KeyError, ValueError, IndexError) as error:
        raise ReaderError(f"{path.name}: malformed Nanonis header ({type(error).__name__}: {error})") from None
    if not kind or kind[0] != "FLOAT":
        raise ReaderError(f"{path.name}: Nanonis data type {' '.join(kind) or 'missing'} (SCANIT_TYPE); "
                          "only FLOAT is read")
    if nx < 1 or ny < 1 or not (width > 0 and height > 0):
        raise ReaderError(f"{path.name}: Nanonis header gives no image (SCAN_PIXELS {nx} {ny}, "
                          f"SCAN_RANGE {width:g} {height:g} m)")
    unknown = sorted({i.get("Direction", "") for i in infos} - set(_DIRECTIONS))
    if unknown or "Name" not in columns:
        raise ReaderError(f"{path.name}: malformed Nanonis :DATA_INFO: table (directions {unknown or 'fine'}, "
                          f"columns {columns})")
    images = [(info, d) for info in infos for d in _DIRECTIONS[info["Direction"]]]
    needed = mark + len(_DATA_MARK) + 4 * nx * ny * len(images)
    if len(raw) < needed:
        raise ReaderError(f"{path.name}: truncated Nanonis file ({len(raw)} bytes, its {len(images)} images "
                          f"need {needed})")
    times = [leading_number(v) for v in _value(scan.header, "SCAN_TIME")[:2]]
    times += [None] * (2 - len(times))
    channels = []
    for info, direction in images:
        name = info["Name"]
        image = scan.get_channel(name, direction=direction)
        data = np.asarray(image.pixels, dtype=np.float64).reshape(ny, nx)
        unit, factor = to_si(info.get("Unit", ""))
        line_time = times[0] if direction == "forward" else times[1]
        channels.append(Channel(name, direction, quantity_of(name, unit), unit,
                                (data[:, ::-1] if direction == "backward" else data) * factor, (width, height),
                                line_time if line_time and line_time > 0 else None))
    metadata = {key.lower(): text for key in
                ("NANONIS_VERSION", "REC_DATE", "REC_TIME", "SCAN_PIXELS", "SCAN_RANGE", "SCAN_TIME")
                if (text := " ".join(_value(scan.header, key)))}
    metadata.update({"slow_scan": " ".join(_value(scan.header, "SCAN_DIR")) or None,
                     "scan_rotation_deg": leading_number(" ".join(_value(scan.header, "SCAN_ANGLE")))})
    return AfmFile(path, "nanonis", tuple(channels), metadata)
