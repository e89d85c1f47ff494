"""Gwyddion ``.gwy`` files, read with the ``gwyfile`` package.

Every ``/N/data`` data field becomes a channel; its title carries name and direction
(``"Z-Axis forward"`` as Gwyddion titles a Nanosurf import, ``"HeightRetrace"``, ``"Topography [Bwd]"``,
``"trace none"`` as ``afmsim run`` writes); a title that is only the direction word (``"trace"``,
``"retrace"``) on a length channel names a channel ``height``, as the ``.npz`` reader names a plain
pair. Units from the fields' ``si_unit_z``/``si_unit_xy``; ``xoff``/``yoff`` give ``Channel.offset_m``.
Rows as stored: a ``.gwy`` keeps no slow-scan direction, so row 0 is taken as the first line
scanned (true for files ``afmsim`` writes; a file converted by Gwyddion from another format may
have been flipped by the import — its ``nanonis`` module reverses an upward frame — and read
backwards in time the stage's slow axis fits no model: docs/diagnosis.md, "Line order matters"). Line time from the channel's metadata (``/N/meta``) where an
import kept it: ``Time/Line`` or ``Line time`` (one direction, as Nanosurf), else ``Scan rate``/
``ScanRate`` (Hz, trace + retrace lines per second, as Bruker and Asylum: ``1 / (2 · rate)``).

The top-level object's declared size is checked against the file's length before ``gwyfile``
parses it: ``gwyfile`` 0.3 loops forever on a cut file.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

from .channels import AfmFile, Channel, ReaderError, quantity_of, split_direction, to_si

__all__ = ["read_gwy_file"]

_MAGIC = b"GWYP"


def _unit(field, key: str) -> tuple[str, float]:
    unit = field.get(key)
    return to_si(str(unit.get("unitstr", "")) if unit is not None else "")


def _line_time(meta) -> float | None:
    """One direction's line time, s, from a channel's metadata container (see the module notes)."""
    if meta is None:
        return None
    entries = {str(k).strip().lower(): str(v) for k, v in meta.items()}
    for keys, per_direction in ((("time/line", "line time"), True), (("scan rate", "scanrate", "line rate (hz)"), False)):
        for key in keys:
            match = re.match(r"\s*([-+0-9.eE]+)\s*(\S*)", entries.get(key, ""))
            if match is None:
                continue
            unit, factor = to_si(match.group(2) or ("s" if per_direction else "Hz"))
            value = float(match.group(1)) * factor
            if value > 0 and unit == ("s" if per_direction else "Hz"):
                return value if per_direction else 1.0 / (2.0 * value)
    return None


def read_gwy_file(path: Path) -> AfmFile:
    """Every data field of a Gwyddion ``.gwy`` file as a channel."""
    from gwyfile.objects import GwyDataField, GwyObject

    raw = path.read_bytes()
    if raw[:4] != _MAGIC:
        raise ReaderError(f"{path.name}: not a Gwyddion .gwy file (no GWYP magic)")
    name_end = raw.find(b"\0", 4)
    if name_end < 0 or len(raw) < name_end + 5:
        raise ReaderError(f"{path.name}: truncated .gwy file (no complete top-level object header)")
    promised = name_end + 5 + struct.unpack("<I", raw[name_end + 1:name_end + 5])[0]
    if len(raw) < promised:
        raise ReaderError(f"{path.name}: truncated .gwy file ({len(raw)} bytes, its top-level object needs {promised})")
    try:
        container = GwyObject.fromfile(str(path))
    except Exception as error:  # gwyfile raises several types on a cut or corrupt file
        raise ReaderError(f"{path.name}: truncated or corrupt .gwy file ({type(error).__name__})") from None
    ids = sorted(int(key.split("/")[1]) for key in container
                 if key.count("/") == 2 and key.endswith("/data") and key.split("/")[1].isdigit()
                 and isinstance(container[key], GwyDataField))
    channels = []
    for i in ids:
        field = container[f"/{i}/data"]
        title = str(container.get(f"/{i}/data/title", f"channel {i}"))
        name, direction = split_direction(title)
        unit, factor = _unit(field, "si_unit_z")
        if direction and name == title.strip() and unit == "m":  # the title is the direction word alone
            name = "height"
        _, lateral = _unit(field, "si_unit_xy")
        data = np.array(field.data, dtype=np.float64) * factor
        size = (float(field.get("xreal", 1.0)) * lateral, float(field.get("yreal", 1.0)) * lateral)
        offset = (float(field.get("xoff", 0.0)) * lateral, float(field.get("yoff", 0.0)) * lateral)
        line_time = _line_time(container.get(f"/{i}/meta"))
        channels.append(Channel(name, direction, quantity_of(name, unit), unit, data, size, line_time, offset))
    if not channels:
        raise ReaderError(f"{path.name}: the .gwy file holds no data fields")
    return AfmFile(path, "gwy", tuple(channels), {"channels_in_file": len(channels)})
