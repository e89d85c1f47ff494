"""Reading real AFM files: every channel of a vendor file, in SI units, with its scan direction.

    from afmsim.readers import read_afm_file, pick_height_pair, pick_error_pair
    afm = read_afm_file("circles.nid")                 # AfmFile: format, channels, metadata
    trace, retrace, picked = pick_height_pair(afm)     # the topography's forward/backward scans
    error = pick_error_pair(afm, trace.shape)           # the Z loop's error signal beside it, or None

Formats and the maintained package that reads each: Nanosurf ``.nid`` (``nsfopen``), Gwyddion
``.gwy`` (``gwyfile``), Asylum/Igor ``.ibw`` (``igor2``), Bruker/Veeco Nanoscope ``.spm`` and
``.000``–``.999`` and Nanonis ``.sxm`` (``pySPM``), Park Systems ``.tiff``/``.tif`` and JPK ``.jpk``
(``SurfaceTopography``), afmsim's own ``.npz`` (numpy). Each module documents how it finds line
order, direction, units and line time in its format (:mod:`.channels` states the common
conventions). A Park file holds one scan direction: :func:`read_afm_files` reads a forward file and
a backward file as one.
Every problem raises :class:`ReaderError` with one line naming the file.
"""

from __future__ import annotations

from pathlib import Path

from .channels import AfmFile, Channel, ReaderError, reversed_lines, scanned_lines
from .gwy import read_gwy_file
from .listing import channel_listing, format_listing
from .ibw import read_ibw
from .nanoscope import is_nanoscope_suffix, read_nanoscope
from .jpk import read_jpk
from .nid import read_nid
from .npz import read_npz
from .park import read_park
from .sxm import read_sxm
from .pick import pick_error_pair, pick_height_pair

__all__ = ["read_afm_file", "read_afm_files", "pick_height_pair", "pick_error_pair", "AfmFile", "Channel", "ReaderError",
           "reader_for", "FORMATS", "channel_listing", "format_listing", "scanned_lines", "reversed_lines"]

FORMATS = ".nid, .gwy, .ibw, .spm, .000–.999, .sxm, .tiff/.tif (Park), .jpk, .npz"
_READERS = {".nid": read_nid, ".gwy": read_gwy_file, ".ibw": read_ibw, ".npz": read_npz, ".tiff": read_park,
            ".tif": read_park, ".jpk": read_jpk, ".sxm": read_sxm}


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


def read_afm_files(*paths) -> AfmFile:
    """Several files of one measurement read as one (a Park forward file and its backward file): the
    channels of each in the order given, the first file's path, format and metadata
    (``metadata["files"]`` lists every file). One path reads as :func:`read_afm_file`.

    Raises :class:`ReaderError` (one line) for an unreadable file or the same file given twice.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise ReaderError("no AFM file given")
    if len({p.resolve() for p in paths}) < len(paths):
        raise ReaderError(f"{paths[0].name}: the same file is given twice; give the file with the other scan direction")
    files = [read_afm_file(p) for p in paths]
    if len(files) == 1:
        return files[0]
    first = files[0]
    metadata = {**first.metadata, "files": [p.name for p in paths]}
    return AfmFile(first.path, first.format, tuple(c for f in files for c in f.channels), metadata)
