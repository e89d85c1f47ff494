"""Nanosurf ``.nid`` files, read with the ``nsfopen`` package (Nanosurf's own reader, MIT).

``nsfopen`` scales the little-endian integers to ``Dim2Min + Dim2Range · (raw + 2^(b-1)) / 2^b``;
this module adds what it leaves out:

* **Validation**: the header must start with ``[DataSet]`` and end in ``#!``, and the data block
  after ``#!`` must hold exactly the bytes the header promises (``nsfopen`` reads them from the file's
  end, so a cut file would otherwise be read as header text; all six bundled files match exactly).
* **Line order**: Nanosurf stores line ``k`` at height ``y = k·Δy`` whatever the slow direction;
  ``CurLine`` (the last line scanned) is ``Lines−1`` when ``Scan direction=Up`` and ``0`` when
  ``Down`` in every bundled file. A ``Down`` scan's rows are reversed, so row 0 is the first line
  scanned. Both directions are stored left → right (``nsfopen`` and Gwyddion's ``ezdfile`` read them
  so; forward and backward of the bundled files correlate 0.6–0.99 as stored, ≤ 0 mirrored).
* **Line time**: ``ScanTime`` of ``[DataSet\\Parameters\\Imaging]`` (newer software, one value per
  direction, both equal), else ``Time/Line`` of ``[DataSet-Info]``. Nanosurf's "Time/Line" is the
  time of one direction: the software quotes an image time of 2 · Lines · Time/Line, and
  ``ScanTime`` holds one such value for the forward and one for the backward line.
* Units from each channel's ``Dim2Unit`` (SI already; ``°`` → ``deg``), sizes from ``Dim0Range``/
  ``Dim1Range``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .channels import AfmFile, Channel, ReaderError, leading_number, quantity_of, to_si

__all__ = ["read_nid"]

_FRAMES = {"Scan forward": ("Forward", "forward", ""), "Scan backward": ("Backward", "backward", ""),
           "2nd scan forward": ("2nd Forward", "forward", " (2nd scan)"),
           "2nd scan backward": ("2nd Backward", "backward", " (2nd scan)")}


def _text(raw: bytes) -> str:
    """Header bytes as text: ISO-8859-1, with UTF-8 sequences (``Âµ``, ``Â°``) repaired."""
    text = raw.decode("latin-1")
    try:
        return text.encode("latin-1").decode("utf-8")
    except UnicodeDecodeError:
        return text


def _sections(header: str) -> dict[str, dict[str, str]]:
    """The INI header as ``{section: {key: value}}`` (``-- title --`` separator lines skipped)."""
    sections: dict[str, dict[str, str]] = {}
    current = None
    for line in header.splitlines():
        line = line.strip()
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
        elif current is not None and "=" in line and not line.startswith("--"):
            key, value = line.split("=", 1)
            current[key.strip()] = value.strip()
    return sections


def _datasets(sections: dict, name: str) -> list[tuple[str, dict]]:
    """``(frame, section)`` of every channel the ``[DataSet]`` groups list, in file order."""
    top = sections.get("DataSet")
    if top is None or "GroupCount" not in top:
        raise ReaderError(f"{name}: not a Nanosurf .nid file (no [DataSet] GroupCount)")
    out = []
    for g in range(int(top["GroupCount"])):
        for c in range(int(top.get(f"Gr{g}-Count", 0))):
            key = top.get(f"Gr{g}-Ch{c}")
            if key is not None:
                if key not in sections:
                    raise ReaderError(f"{name}: header lists channel section [{key}] but lacks it")
                out.append((sections[key].get("Frame", ""), sections[key]))
    return out


def _seconds(text: str | None) -> float | None:
    """``"500ms"``, ``"2 s"``, ``"V[0.78,0.78,0]*[s,s,s]"`` → seconds."""
    if not text:
        return None
    match = (re.match(r"V\[([^,\]]+)[^\]]*\]\*\[([^,\]]*)", text)
             or re.match(r"\s*([-+0-9.eE]+)\s*(\S*)", text))
    if match is None:
        return None
    value, unit = match.groups()
    si, factor = to_si(unit or "s")
    try:
        seconds = float(value) * factor
    except ValueError:
        return None
    return seconds if si == "s" and seconds > 0 else None


def read_nid(path: Path) -> AfmFile:
    """Every image channel of a Nanosurf ``.nid`` file (see the module notes for the conventions)."""
    raw = path.read_bytes()
    if not raw.startswith(b"[DataSet]"):
        raise ReaderError(f"{path.name}: not a Nanosurf .nid file (it does not start with [DataSet])")
    marker = raw.find(b"#!")
    if marker < 0:
        raise ReaderError(f"{path.name}: truncated Nanosurf file (no '#!' data marker after the header)")
    sections = _sections(_text(raw[:marker]))
    try:
        datasets = _datasets(sections, path.name)
        promised = sum(int(s["Points"]) * int(s["Lines"]) * int(s["SaveBits"]) // 8 for _, s in datasets)
        bits = {int(s["SaveBits"]) for _, s in datasets}
    except (KeyError, ValueError) as error:
        raise ReaderError(f"{path.name}: malformed Nanosurf header ({type(error).__name__}: {error})") from None
    stored = len(raw) - marker - 2
    if stored < promised:
        raise ReaderError(f"{path.name}: truncated Nanosurf file (data block {stored} bytes, header promises "
                          f"{promised})")
    if stored > promised:  # nsfopen reads the data from the file's end, Gwyddion from '#!': they would disagree
        raise ReaderError(f"{path.name}: {stored - promised} bytes more after '#!' than the header's channels "
                          "hold; cannot tell where the data start")
    if not bits <= {16, 32} or len(bits) > 1:
        raise ReaderError(f"{path.name}: SaveBits {sorted(bits)} not supported (16 or 32, the same for all channels)")
    from NSFopen.read import nid_read

    try:
        images = nid_read(str(path), dataframe=False).data.get("Image", {})
    except Exception as error:  # nsfopen raises whatever its parsing meets on a corrupt file
        raise ReaderError(f"{path.name}: unreadable Nanosurf file ({type(error).__name__}: "
                          f"{str(error).splitlines()[0] if str(error) else ''})") from None
    info = sections.get("DataSet-Info", {})
    imaging = sections.get("DataSet\\Parameters\\Imaging", {})
    line_time = _seconds(imaging.get("ScanTime")) or _seconds(info.get("Time/Line"))
    down = info.get("Scan direction", "Up").strip().lower() == "down"
    channels, seen = [], set()
    for frame, section in datasets:
        if frame not in _FRAMES or int(section.get("Lines", 0)) < 2:
            continue  # spectroscopy, sweeps and single lines are not images
        group, direction, qualifier = _FRAMES[frame]
        name = section.get("Dim2Name", "")
        key = name if (frame, name) not in seen else name + "2"  # nsfopen's naming of a repeated channel
        seen.add((frame, name))
        data = images.get(group, {}).get(key)
        if data is None or np.ndim(data) != 2:
            continue
        unit, factor = to_si(section.get("Dim2Unit", ""))
        data = np.asarray(data, dtype=np.float64) * factor
        size = tuple(float(section[f"Dim{i}Range"]) * to_si(section.get(f"Dim{i}Unit", "m"))[1] for i in (0, 1))
        channels.append(Channel(name + qualifier, direction, quantity_of(name, unit), unit,
                                data[::-1].copy() if down else data, size, line_time))
    if not channels:
        raise ReaderError(f"{path.name}: no image channels (only spectroscopy or empty groups)")
    metadata = {k: v for k, v in info.items() if v and not set(v) <= {"-"}}
    metadata.update({"slow_scan": "down" if down else "up", "rows_reversed_to_acquisition_order": down,
                     "scan_rotation_deg": leading_number(info.get("Rotation")),
                     "line_time_source": "ScanTime" if _seconds(imaging.get("ScanTime")) else "Time/Line"})
    return AfmFile(path, "nid", tuple(channels), metadata)
