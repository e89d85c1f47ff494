"""JPK Instruments (now Bruker) ``.jpk`` image scans, read with ``SurfaceTopography``'s ``JPKReader``.

A ``.jpk`` file is a multi-page TIFF: page 0 a thumbnail carrying the scan's tags (grid size
``GridULength``/``GridVLength`` in m, line rate ``ScanrateFrequency``), then one page per channel and
direction, whose private tags name the channel (``ChannelFancyName``: ``Height``, ``Height (measured)``,
…), say whether it is the retrace (``ChannelRetrace``) and give the linear scaling of its default
slot (``ScalingMultiply · raw + ScalingOffset`` in the slot's unit). ``SurfaceTopography`` applies
that scaling, as Gwyddion's ``jpkscan`` module does; this module takes from it:

* direction: ``ChannelRetrace`` (``trace``/``retrace``); the name is ``ChannelFancyName`` without
  the ``, retrace`` marker the reader appends; columns as stored, left → right for both directions;
* rows: JPK stores the first line scanned first; ``SurfaceTopography`` flips them to display
  order (the first line at the bottom), so they are flipped back;
* size: the grid lengths (m); ``GridTheta`` (rad) is reported as the scan rotation; line time from ``ScanrateFrequency`` (Hz, trace + retrace lines per
  second, as Bruker's and Asylum's scan rate: one direction lasts ``1 / (2 · rate)``).

``SurfaceTopography`` lists only the channels whose default slot is a length (heights); the others
(deflection in V, error signals) are not listed.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .channels import AfmFile, Channel, ReaderError, quantity_of, to_si

__all__ = ["read_jpk"]


def _base_name(fancy: str) -> str:
    """``Height (measured, retrace)`` → ``Height (measured)``; ``Height (retrace)`` → ``Height``."""
    name = re.sub(r",\s*retrace\)$", ")", fancy.strip())
    return re.sub(r"\s*\(retrace\)$", "", name).strip()


def read_jpk(path: Path) -> AfmFile:
    """Every height channel of a JPK image scan (see the module notes for the conventions)."""
    from SurfaceTopography.IO.JPK import JPKReader

    try:
        reader = JPKReader(str(path))
        listed = list(reader.channels)
        channels = []
        for index, listed_channel in enumerate(listed):
            header = listed_channel.info["raw_metadata"]
            topography = reader.topography(channel_index=index)
            unit, factor = to_si(topography.unit or "m")
            data = np.asarray(topography.heights(), dtype=np.float64).T[::-1] * factor
            name = _base_name(str(header.get("ChannelFancyName") or listed_channel.name))
            size_x, size_y = (float(s) * factor for s in listed_channel.physical_sizes)
            rate = float(header.get("ScanrateFrequency") or 0.0)
            channels.append(Channel(name, "retrace" if header.get("ChannelRetrace") else "trace",
                                    quantity_of(name, unit), unit, np.ascontiguousarray(data), (size_x, size_y),
                                    1.0 / (2.0 * rate) if rate > 0 else None))
    except ReaderError:
        raise
    except Exception as error:  # SurfaceTopography's format checks, truncated pages: one line, no traceback
        first = str(error).splitlines()[0] if str(error) else ""
        raise ReaderError(f"{path.name}: unreadable JPK image scan ({type(error).__name__}: {first})") from None
    if not channels:
        raise ReaderError(f"{path.name}: no height channel in the JPK file (SurfaceTopography lists length channels only)")
    header = listed[0].info["raw_metadata"]
    metadata = {"program": str(header.get("ProgramVersion", "")) or None,
                "start_date": str(header.get("StartDate", "")) or None,
                "scan_rate_hz": float(header.get("ScanrateFrequency") or 0.0) or None,
                "scan_rotation_deg": float(np.degrees(float(header.get("GridTheta") or 0.0))) or None,
                "feedback_mode": str(header.get("FeedbackMode", "")) or None}
    return AfmFile(path, "jpk", tuple(channels), metadata)
