"""Park Systems ``.tiff``/``.tif`` files, read with ``SurfaceTopography``'s ``PSReader``.

A Park Systems TIFF is an ordinary TIFF (an 8-bit picture of the image) whose private tags hold the
measurement: ``50432`` the PSIA magic number, ``50433`` the version, ``50434`` the data, ``50435``
the scan header. One file holds one channel in one scan direction, so a forward/backward pair is
two files (``afmsim diagnose --measured FORWARD --retrace BACKWARD``). ``SurfaceTopography``
parses both header versions and scales the stored numbers as Gwyddion's ``psia`` module does:
``data_gain · (data_scale_factor · raw + data_offset)`` in the header's unit (µm when none is given).
What this module takes from the header (``PSReader``'s ``raw_metadata``):

* name: ``source_name`` (``Z Height``, ``Z Detector``, …);
* direction: ``forward`` (fast scan left → right: ``forward``, else ``backward``); columns are kept in
  their stored order, left → right on the image for both directions;
* rows: Park stores the image's bottom line first (as Gwyddion and ``SurfaceTopography`` read it), so
  they are already in acquisition order for an upward slow scan (``scan_up``) and reversed for a
  downward one;
* size: ``physical_size_x``/``_y`` (µm); line time from ``scan_rate`` (Hz, trace + retrace lines per
  second, as Bruker's and Asylum's scan rate: one direction lasts ``1 / (2 · rate)``);
* ``angle`` is the scan rotation; ``swap_xy`` (fast axis along the image's y) is reported in the
  metadata, the image is kept as stored.

``SurfaceTopography`` converts every Park channel to µm, so a channel in another unit (an amplitude
in V, a phase in degrees) cannot be read: it gets one line saying so. Line-profile and
spectroscopy files are refused the same way.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .channels import AfmFile, Channel, ReaderError, quantity_of, to_si

__all__ = ["read_park"]

_PSIA_MAGIC_TAG = 50432


def _is_park_tiff(path: Path) -> bool:
    """Whether the TIFF at ``path`` carries the PSIA magic-number tag (any TIFF that does not is foreign)."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            return len(tif.pages) > 0 and _PSIA_MAGIC_TAG in tif.pages[0].tags
    except (tifffile.TiffFileError, ValueError, EOFError) as error:
        raise ReaderError(f"{path.name}: not a readable TIFF file ({type(error).__name__}: "
                          f"{str(error).splitlines()[0] if str(error) else ''})") from None


def read_park(path: Path) -> AfmFile:
    """The one channel of a Park Systems TIFF (see the module notes for the conventions)."""
    if not _is_park_tiff(path):
        raise ReaderError(f"{path.name}: a TIFF without Park Systems' PSIA tags (not an AFM image file "
                          "afmsim can read)")
    from SurfaceTopography.IO.PS import PSReader

    try:
        reader = PSReader(str(path))
        channel = reader.channels[0]
        header = channel.info["raw_metadata"]
        topography = reader.topography(channel_index=0)
        heights = np.asarray(topography.heights(), dtype=np.float64).T
    except ValueError as error:  # SurfaceTopography's unit conversion and format checks
        text = str(error).splitlines()[0] if str(error) else type(error).__name__
        if "cannot convert" in text.lower():
            text = "only length channels are read from Park files (SurfaceTopography converts to µm)"
        raise ReaderError(f"{path.name}: unreadable Park Systems TIFF: {text}") from None
    except Exception as error:  # truncated data, unsupported version/type: one line, no traceback
        first = str(error).splitlines()[0] if str(error) else ""
        raise ReaderError(f"{path.name}: unreadable Park Systems TIFF ({type(error).__name__}: {first})") from None
    unit, factor = to_si(topography.unit or "µm")
    heights = heights[::-1] * factor  # SurfaceTopography's rows run top → bottom; stored (and here) bottom first
    up = bool(header.get("scan_up", 1))
    data = heights if up else heights[::-1].copy()
    name = str(header.get("source_name") or channel.name or "Z Height").strip()
    size_x, size_y = (float(s) * 1e-6 for s in channel.physical_sizes)
    rate = float(header.get("scan_rate") or 0.0)
    line_time = 1.0 / (2.0 * rate) if rate > 0 else None
    direction = "forward" if header.get("forward", 1) else "backward"
    channels = (Channel(name, direction, quantity_of(name, unit), unit, np.ascontiguousarray(data),
                        (size_x, size_y), line_time),)
    metadata = {"head_mode": str(header.get("image_mode", "")), "scan_rate_hz": rate or None,
                "slow_scan": "up" if up else "down", "rows_reversed_to_acquisition_order": not up,
                "scan_rotation_deg": float(header.get("angle", 0.0)) or None,
                "swap_xy": bool(header.get("swap_xy", 0)), "data_unit": str(header.get("data_unit", ""))}
    return AfmFile(path, "park", channels, metadata)
