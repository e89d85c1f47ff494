"""Asylum Research / Igor ``.ibw`` images, read with the ``igor2`` package (binary wave v1–5).

Asylum saves one wave of shape (points, lines, channels) with the channel names as the labels
of the third dimension (``HeightTrace``, ``HeightRetrace``, ``ZSensorTrace``, ``AmplitudeRetrace``…)
and a wave note of ``Key: value`` lines. From the note: ``FastScanSize``/``SlowScanSize`` (m;
otherwise the wave's x/y scaling), ``ScanRate`` (Hz, lines per second with a line = trace +
retrace, so one direction lasts ``1 / (2 · ScanRate)``) and ``ScanDown`` (1: the frame was scanned
top to bottom). Igor's row 0 is the image's bottom line, so rows are reversed only for a
``ScanDown`` frame. Trace and retrace are both stored left → right (the Asylum software shows them
unflipped side by side). The wave carries one data unit for all layers: a single-channel wave uses
it; in a multi-channel wave each channel gets the SI unit of its kind (m for height, deflection
and amplitude, ° for phase, A for current, V otherwise), which is what Asylum stores.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .channels import AfmFile, Channel, ReaderError, leading_number, quantity_of, split_direction, to_si

__all__ = ["read_ibw"]

_KIND_UNIT = {"height": "m", "deflection": "m", "amplitude": "m", "phase": "deg", "current": "A",
              "lateral": "V", "other": ""}


def _note(raw) -> dict[str, str]:
    text = raw.decode("latin-1") if isinstance(raw, bytes) else str(raw)
    pairs = (line.split(":", 1) for line in text.replace("\n", "\r").split("\r") if ":" in line)
    return {key.strip(): value.strip() for key, value in pairs}


def _number(note: dict, key: str) -> float | None:
    try:
        value = float(note.get(key, "").split("@")[0].split()[0])
    except (ValueError, IndexError):
        return None
    return value if np.isfinite(value) and value > 0 else None


def _units(header) -> tuple[str, list[str]]:
    join = lambda chars: b"".join(bytes(c) for c in np.atleast_1d(chars)).decode("latin-1").strip()  # noqa: E731
    return join(header["dataUnits"]), [join(row) for row in header["dimUnits"]]


def read_ibw(path: Path) -> AfmFile:
    """Every image layer of an Igor binary wave (Asylum Research ``.ibw``)."""
    from igor2 import binarywave

    logging.getLogger("igor2").addHandler(logging.NullHandler())  # its errors on a cut file go to ReaderError only
    try:
        wave = binarywave.load(str(path))["wave"]
    except Exception as error:  # igor2 raises struct/value/key errors on foreign or cut files
        raise ReaderError(f"{path.name}: not a readable Igor binary wave ({type(error).__name__})") from None
    data = np.asarray(wave["wData"])
    if data.ndim not in (2, 3) or data.shape[0] < 2 or data.shape[1] < 2 or data.dtype.kind not in "iuf":
        raise ReaderError(f"{path.name}: the wave is not an image stack (shape {data.shape}, dtype {data.dtype})")
    data = data.reshape(data.shape[0], data.shape[1], -1)
    header = wave["wave_header"]
    data_unit, dim_units = _units(header)
    note = _note(wave.get("note", b""))
    labels = [lab.decode("latin-1") for lab in (wave["labels"][2] if len(wave["labels"]) > 2 else [])][1:]
    points, lines, layers = data.shape
    xy_unit = to_si(dim_units[0] or "m")[1]
    size = (_number(note, "FastScanSize") or float(header["sfA"][0]) * points * xy_unit,
            _number(note, "SlowScanSize") or float(header["sfA"][1]) * lines * xy_unit)
    rate = _number(note, "ScanRate")
    line_time = 1.0 / (2.0 * rate) if rate else None
    down = note.get("ScanDown", "0").strip() in ("1", "Down", "down")
    channels = []
    for k in range(layers):
        bname = header["bname"]
        title = labels[k] if k < len(labels) and labels[k] else \
            (bname.decode("latin-1") if isinstance(bname, bytes) else str(bname))
        name, direction = split_direction(title)
        quantity = quantity_of(name, "")
        unit, factor = to_si(data_unit if layers == 1 and data_unit else _KIND_UNIT[quantity])
        quantity = quantity_of(name, unit)
        image = data[:, :, k].T.astype(np.float64) * factor  # (lines, points), row 0 = bottom line
        channels.append(Channel(name, direction, quantity, unit, image[::-1].copy() if down else image, size,
                                line_time))
    metadata = {k: note[k] for k in ("ImagingMode", "ScanAngle", "ScanRate", "ScanLines", "ScanPoints",
                                     "FastScanSize", "SlowScanSize", "Date", "Time") if k in note}
    metadata.update({"slow_scan": "down" if down else "up", "rows_reversed_to_acquisition_order": down,
                     "scan_rotation_deg": leading_number(note.get("ScanAngle"))})
    return AfmFile(path, "ibw", tuple(channels), metadata)
