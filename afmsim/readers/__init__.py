"""Reading real AFM files: every channel of a vendor file, in SI units, with its scan direction.

    from afmsim.readers import read_afm_file, pick_height_pair
    afm = read_afm_file("circles.nid")                 # AfmFile: format, channels, metadata
    trace, retrace, picked = pick_height_pair(afm)     # the topography's forward/backward scans

Formats and the maintained package that reads each: Nanosurf ``.nid`` (``nsfopen``), Gwyddion
``.gwy`` (``gwyfile``), Asylum/Igor ``.ibw`` (``igor2``), Bruker/Veeco Nanoscope ``.spm`` and
``.000``–``.999`` (``pySPM``), afmsim's own ``.npz`` (numpy). Each module documents how it finds
line order, direction, units and line time in its format (:mod:`.channels` states the common
conventions). Park ``.tiff`` is not read: no maintained Python reader handles it.
Every problem raises :class:`ReaderError` with one line naming the file.
"""

from __future__ import annotations

from pathlib import Path

from .channels import AfmFile, Channel, ReaderError
from .gwy import read_gwy_file
from .listing import channel_listing, format_listing
from .ibw import read_ibw
from .nanoscope import is_nanoscope_suffix, read_nanoscope
from .nid import read_nid
from .npz import read_npz
from .pick import pick_height_pair

__all__ = ["read_afm_file", "pick_height_pair", "AfmFile", "Channel", "ReaderError", "reader_for", "FORMATS",
           "channel_listing", "format_listing"]

FORMATS = ".nid, .gwy, .ibw, .spm, .000–.999, .npz"
_READERS = {".nid": read_nid, ".gwy": read_gwy_file, ".ibw": read_ibw, ".npz": read_npz}


def reader_for(path) -> callable | None:
    """The reader function for a file's suffix, or None for a suffix no reader knows."""
    suffix = Path(path).suffix.lower()
    return _READERS.get(suffix) or (read_nanoscope if is_nanoscope_suffix(suffix) else None)


def read_afm_file(path) -> AfmFile:
    """Read every channel of an AFM image file (format chosen by the suffix).

    Raises :class:`ReaderError` (one line) for a missing, empty, truncated or foreign file.
    """
    path = Path(path)
    if not path.is_file():
        raise ReaderError(f"{path}: {'a folder, not a file' if path.is_dir() else 'no such file'}")
    reader = reader_for(path)
    if reader is None:
        raise ReaderError(f"{path.name}: unknown AFM file type '{path.suffix}'; readable: {FORMATS}")
    if path.stat().st_size == 0:
        raise ReaderError(f"{path.name}: empty file")
    try:
        return reader(path)
    except ReaderError:
        raise
    except OSError as error:
        raise ReaderError(f"{path.name}: cannot read ({error.strerror or error})") from None
    except Exception as error:  # a vendor reader failing on a file it half understands: one line, no traceback
        first = str(error).splitlines()[0] if str(error) else ""
        raise ReaderError(f"{path.name}: unreadable {path.suffix} file ({type(error).__name__}: {first})") from None
