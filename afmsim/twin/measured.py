"""A measured forward/backward pair from a vendor file, through :mod:`afmsim.readers`."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from afmsim.readers import ReaderError, pick_height_pair, read_afm_files, scanned_lines

from .raster import RealScan

__all__ = ["MeasuredPair", "load_measured_pair", "overscan_from_metadata"]


@dataclass(frozen=True)
class MeasuredPair:
    """Trace and retrace heights (m, (lines, pixels), left → right, rows in acquisition order) and the scan."""

    path: Path
    trace: np.ndarray
    retrace: np.ndarray
    scan: RealScan
    overscan_fraction: float | None
    picked: str
    metadata: dict


def overscan_from_metadata(metadata: dict) -> float | None:
    """The overscan as a fraction of the image width, from a header entry named like "Overscan" ("5 %" → 0.05)."""
    for key, value in metadata.items():
        if "overscan" in str(key).lower():
            match = re.search(r"[-+]?\d+(?:\.\d+)?", str(value))
            if match:
                number = float(match.group())
                return number / 100.0 if ("%" in str(value) or number > 1) else number
    return None


def load_measured_pair(path, channel: str | None = None, line_time_s: float | None = None,
                       retrace=None) -> MeasuredPair:
    """Read ``path``'s height trace/retrace; ``line_time_s`` (one direction, s) overrides or supplies the header's.
    ``retrace``: a second file with the other scan direction (Park writes one direction per file).

    A frame stopped before its end is read up to its last scanned line, the scan height cut in
    proportion (:func:`afmsim.readers.scanned_lines`).

    Raises ``ValueError`` (one line) when the file cannot be read, has one direction only, no line
    time, or non-finite heights in more than 1 % of the pixels (the rest are filled from their row).
    """
    try:
        afm = read_afm_files(path, *([] if retrace is None else [retrace]))
        trace, backward, picked = pick_height_pair(afm, channel)
    except ReaderError as error:
        raise ValueError(str(error)) from None
    line_time = line_time_s if line_time_s is not None else trace.line_time_s
    if line_time is None or not line_time > 0:
        raise ValueError(f"{Path(path).name}: the file gives no line time; pass --line-time-s (one scan direction, s)")
    images = []
    scanned = scanned_lines(trace.data, backward.data, min_lines=8)  # a frame stopped early: its scanned lines
    for channel_data in (trace, backward):
        z = np.array(channel_data.data[:scanned], dtype=np.float64)
        bad = ~np.isfinite(z)
        if bad.mean() > 0.01:
            raise ValueError(f"{Path(path).name}: {bad.mean():.1%} of the {channel_data.direction} heights are not finite")
        if bad.any():
            z[bad] = np.nanmedian(z)
        images.append(z)
    lines, pixels = images[0].shape
    if pixels < 32 or lines < 8:
        raise ValueError(f"{Path(path).name}: {lines}×{pixels} px is too small (need ≥ 8 lines of ≥ 32 pixels)")
    size_y = float(trace.size_m[1]) * scanned / trace.shape[0]  # the scan height of the lines scanned
    scan = RealScan((float(trace.size_m[0]), size_y), pixels, lines, float(line_time))
    return MeasuredPair(Path(path), images[0], images[1], scan, overscan_from_metadata(afm.metadata), picked,
                        dict(afm.metadata))
