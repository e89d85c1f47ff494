"""Bruker/Veeco Nanoscope files (``.spm``, ``.000``–``.999``), read with ``pySPM``'s ``Bruker`` class.

``pySPM`` parses the ``\\*Ciao image list`` blocks and scales each layer to the ``@2:Z scale``
soft scale (e.g. ``Sens. Zsens``, nm/V) given in the ``\\*Scanner list``; this module checks the file
before handing it over (``pySPM`` loops forever on a file without ``\\*File list end``, and reads
past the end of a cut one) and adds from the header what ``pySPM`` leaves out:

* direction per layer from ``Line Direction`` (``Trace``/``Retrace``);
* line time from ``Scan Rate`` of the ``\\*Ciao scan list`` (Hz, lines per second where a line is
  trace + retrace, so one direction lasts ``1 / (2 · Scan Rate)``);
* ``Frame direction``: Nanoscope stores the image's bottom line first (Gwyddion and AFMReader flip
  it for display), so rows are reversed only for a ``Down`` frame;
* the image shape: ``pySPM`` 0.6 reshapes a layer to (Samps/line, Number of lines), wrong for a
  non-square image, so the scaled values are re-shaped to (Number of lines, Samps/line) in their
  stored order; the size is ``Scan Size`` along x and ``Scan Size · lines / samples`` along y
  (square pixels, as ``pySPM`` and AFMReader take it).

Text-mode (``?*File list``) files are refused (``pySPM`` reads binary ones only).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .channels import AfmFile, Channel, ReaderError, leading_number, quantity_of, to_si

__all__ = ["read_nanoscope", "is_nanoscope_suffix"]

_MAGIC = b"\\*File list"
_END = b"\\*File list end"


def is_nanoscope_suffix(suffix: str) -> bool:
    """``.spm`` or a three-digit numbered suffix (``.000``–``.999``)."""
    return suffix.lower() == ".spm" or re.fullmatch(r"\.\d{3}", suffix) is not None


def _header_value(header: str, key: str) -> str | None:
    match = re.search(r"^\\" + re.escape(key) + r":\s*(.*?)\s*$", header, flags=re.MULTILINE)
    return match.group(1) if match else None


def read_nanoscope(path: Path) -> AfmFile:
    """Every image layer of a binary Nanoscope file (v4.3 and later headers)."""
    import pySPM

    raw = path.read_bytes()
    if not raw.startswith(_MAGIC):
        hint = " (text-mode Nanoscope files are not supported)" if raw.startswith(b"?*File list") else ""
        raise ReaderError(f"{path.name}: not a binary Nanoscope file (no \\*File list header){hint}")
    end = raw.find(_END)
    if end < 0:
        raise ReaderError(f"{path.name}: truncated Nanoscope file (no \\*File list end in the header)")
    header = raw[:end].decode("latin-1").replace("\r\n", "\n")
    try:
        scan = pySPM.Bruker(str(path))
        layers = [(i, layer) for i, layer in enumerate(scan.layers) if b"@2:Image Data" in layer]
        for i, layer in layers:
            stop = int(layer[b"Data offset"][0]) + int(layer[b"Data length"][0])
            if stop > len(raw):
                raise ReaderError(f"{path.name}: truncated Nanoscope file (layer {i} ends at byte {stop}, "
                                  f"file has {len(raw)})")
    except (KeyError, ValueError, IndexError) as error:
        if isinstance(error, ReaderError):
            raise
        raise ReaderError(f"{path.name}: malformed Nanoscope header ({type(error).__name__}: {error})") from None
    rate = _header_value(header, "Scan Rate") or _header_value(header, "Scan rate")
    try:
        line_time = 1.0 / (2.0 * float(rate.split()[0])) if rate else None
    except (ValueError, ZeroDivisionError, IndexError):
        line_time = None
    down = (_header_value(header, "Frame direction") or "Up").lower().startswith("down")
    channels, skipped = [], []
    for i, layer in layers:
        title = layer[b"@2:Image Data"][0].decode("latin-1")
        quoted = re.search(r'"([^"]*)"', title)
        name = quoted.group(1) if quoted else title
        retrace = layer.get(b"Line Direction", [b"Trace"])[0].strip().lower() == b"retrace"
        try:
            image = scan.get_channel(name, backward=retrace, lazy=False)
        except Exception as error:  # pySPM raises bare Exception / re errors for a scale it cannot parse
            skipped.append(f"{name} ({type(error).__name__})")
            continue
        unit, factor = to_si(image.zscale)
        lines, samples = int(layer[b"Number of lines"][0]), int(layer[b"Samps/line"][0])
        data = np.asarray(image.pixels, dtype=np.float64).reshape(lines, samples) * factor
        width = image.size["real"]["x"] * to_si(image.size["real"]["unit"])[1]
        size = (width, width * lines / samples)
        channels.append(Channel(name, "retrace" if retrace else "trace", quantity_of(name, unit), unit,
                                data[::-1].copy() if down else data, size, line_time))
    if not channels:
        raise ReaderError(f"{path.name}: no readable image layers (\\*Ciao image list) in the Nanoscope file"
                          + (f"; unscalable: {', '.join(skipped)}" if skipped else ""))
    metadata = {key: value for key in ("Version", "Date", "Operating mode", "Scan Size", "Scan Rate", "Samps/line",
                                       "Lines", "Rotate Ang.") if (value := _header_value(header, key))}
    metadata.update({"slow_scan": "down" if down else "up", "rows_reversed_to_acquisition_order": down,
                     "scan_rotation_deg": leading_number(_header_value(header, "Rotate Ang.")),
                     "skipped_layers": skipped})
    return AfmFile(path, "nanoscope", tuple(channels), metadata)
