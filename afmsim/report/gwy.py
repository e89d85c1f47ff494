"""Gwyddion ``.gwy`` export and import of height maps (via the ``gwyfile`` package).

One ``GwyDataField`` per channel, channel ``i`` stored under the container keys ``/i/data`` and
``/i/data/title`` (the layout Gwyddion itself writes), with

* ``xreal, yreal`` = physical width/height ``nx·dx, ny·dy`` in metres,
* ``xoff, yoff``   = position of the field's top-left *corner* in metres. Gwyddion's pixel ``j``
  spans ``[xoff + j·dx, xoff + (j+1)·dx]``, while :class:`~afmsim.samples.heightmap.HeightMap`
  keeps the *centre* of pixel ``[0, 0]`` in ``origin``, so ``xoff = origin_x − dx/2``
  (likewise for y),
* SI unit ``"m"`` on x/y and on z; data rows = scan lines along +y (Gwyddion's row order, no flip).

Because ``xreal/xres`` and ``xoff + dx/2`` can differ from the original floats by an ulp, the
exact pixel size and origin are also kept (as ``repr`` strings) in the channel's metadata
container ``/i/meta`` (visible in Gwyddion's metadata browser, beside any ``meta`` text the writer
adds, e.g. a run's line rate and scenario); :func:`read_gwy` uses them only
when they agree with the geometry fields, so a file cropped or resampled in Gwyddion is still
read from its own geometry.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from gwyfile.objects import GwyContainer, GwyDataField, GwyObject, GwySIUnit

from afmsim.samples.heightmap import HeightMap

__all__ = ["write_gwy", "read_gwy"]

_META_PIXEL = "afmsim pixel size (m)"
_META_ORIGIN = "afmsim origin, pixel-centre (m)"

# Length units Gwyddion may write, as multipliers to metres (for files not written by afmsim).
_LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "µm": 1e-6, "um": 1e-6, "\u03bcm": 1e-6, "nm": 1e-9,
                 "pm": 1e-12, "Å": 1e-10}


def write_gwy(path, channels: dict[str, HeightMap], meta: dict[str, str] | None = None) -> Path:
    """Write height maps as the channels of one Gwyddion ``.gwy`` file, atomically.

    Parameters
    ----------
    path : str or Path
        Destination file; its directory must exist. Written via a temporary file in the same
        directory and ``os.replace``, so readers never see a half-written file.
    channels : dict[str, HeightMap]
        Channel title (e.g. ``"trace none"``, ``"retrace diapi"``, ``"topography"``) → map,
        stored in dict order as channels 0, 1, …
    meta : dict[str, str], optional
        Text added to every channel's metadata (Gwyddion's metadata browser), e.g. the scan's
        line rate and the scenario that made it.

    Returns
    -------
    Path
        The written path.
    """
    path = Path(path)
    if not channels:
        raise ValueError("write_gwy needs at least one channel")
    container = GwyContainer()
    for i, (title, hmap) in enumerate(channels.items()):
        if not isinstance(title, str) or not title:
            raise ValueError(f"channel titles must be non-empty strings, got {title!r}")
        if not isinstance(hmap, HeightMap):
            raise TypeError(f"channel {title!r}: expected HeightMap, got {type(hmap).__name__}")
        ny, nx = hmap.shape
        dx, dy = hmap.pixel_size
        x0, y0 = hmap.origin
        field = GwyDataField(
            np.ascontiguousarray(hmap.z, dtype=np.float64),
            xreal=float(nx * dx), yreal=float(ny * dy),
            xoff=float(x0 - dx / 2), yoff=float(y0 - dy / 2),
            si_unit_xy=GwySIUnit(unitstr="m"), si_unit_z=GwySIUnit(unitstr="m"),
        )
        container[f"/{i}/data"] = field
        container[f"/{i}/data/title"] = title
        # gwyfile guesses typecode 'c' (single char) for 1-character strings; Gwyddion wants 's'.
        container.typecodes[f"/{i}/data/title"] = "s"
        info = GwyContainer()
        info[_META_PIXEL] = f"{dx!r} {dy!r}"
        info[_META_ORIGIN] = f"{x0!r} {y0!r}"
        for key, value in (meta or {}).items():
            info[str(key)] = str(value)
        info.typecodes.update({k: "s" for k in info})
        container[f"/{i}/meta"] = info
        container[f"/{i}/data/visible"] = i == 0
        container.typecodes[f"/{i}/data/visible"] = "b"

    blob = b"GWYP" + container.serialize()
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(blob)
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the file ordinary permissions
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return path


def _unit_scale(unit, what: str, channel: str) -> float:
    """Multiplier to metres for a GwySIUnit (missing or empty → metres assumed)."""
    s = unit.unitstr.strip() if isinstance(unit, GwyObject) and "unitstr" in unit else ""
    if s in ("", "m"):
        return 1.0
    try:
        return _LENGTH_UNITS[s]
    except KeyError:
        raise ValueError(f"channel {channel!r}: {what} unit {s!r} is not a length unit") from None


def _meta_pair(meta, key):
    try:
        a, b = (float(v) for v in str(meta[key]).split())
        return a, b
    except (KeyError, TypeError, ValueError):
        return None


def read_gwy(path) -> dict[str, HeightMap]:
    """Read every data field of a ``.gwy`` file as ``{title: HeightMap}`` (metres).

    Channels come in channel-number order. Lengths in other SI length units (nm, µm, …) are
    converted to metres. A repeated title gets `` (2)``, `` (3)``, … appended.
    """
    obj = GwyObject.fromfile(str(path))  # gwyfile only opens ``str`` paths, not Path objects
    ids = []
    for key in obj:
        parts = key.split("/")
        if len(parts) == 3 and parts[0] == "" and parts[2] == "data" and parts[1].isdigit() \
                and isinstance(obj[key], GwyDataField):
            ids.append(int(parts[1]))
    out: dict[str, HeightMap] = {}
    for i in sorted(ids):
        field = obj[f"/{i}/data"]
        title = str(obj.get(f"/{i}/data/title", f"channel {i}"))
        sxy = _unit_scale(field.get("si_unit_xy"), "x/y", title)
        sz = _unit_scale(field.get("si_unit_z"), "z", title)
        z = np.array(field.data, dtype=np.float64) * sz
        ny, nx = z.shape
        xreal = float(field.get("xreal", 1.0)) * sxy  # Gwyddion's defaults for missing fields
        yreal = float(field.get("yreal", 1.0)) * sxy
        dx, dy = xreal / nx, yreal / ny
        x0 = float(field.get("xoff", 0.0)) * sxy + dx / 2
        y0 = float(field.get("yoff", 0.0)) * sxy + dy / 2
        meta = obj.get(f"/{i}/meta")
        if isinstance(meta, GwyObject):
            px, org = _meta_pair(meta, _META_PIXEL), _meta_pair(meta, _META_ORIGIN)
            if px and org and np.allclose(px, (dx, dy), rtol=1e-9, atol=0) and np.allclose(
                    org, (x0, y0), rtol=0, atol=1e-9 * min(dx, dy)):
                (dx, dy), (x0, y0) = px, org
        name, k = title, 2
        while name in out:
            name, k = f"{title} ({k})", k + 1
        out[name] = HeightMap(z, pixel_size=(dx, dy), origin=(x0, y0))
    return out
