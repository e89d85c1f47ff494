"""What ``afmsim inspect`` prints: a file's channels as a dict (``--json``) or as a table."""

from __future__ import annotations

from .channels import AfmFile, ReaderError
from .pick import pick_error_pair, pick_height_pair

__all__ = ["channel_listing", "format_listing"]


def channel_listing(afm: AfmFile) -> dict:
    """``{"format", "channels": [{name, direction, quantity, unit, shape, size_m, line_time_s}], "picked",
    "error_signal"}``.

    ``picked`` is the one line :func:`pick_height_pair` says (what ``diagnose`` would use), or why
    no pair can be picked; ``error_signal`` the name of the Z loop's error signal that ``diagnose``
    reads beside it (:func:`pick_error_pair`), or None.
    """
    error = None
    try:
        trace, _, picked = pick_height_pair(afm)
        error = pick_error_pair(afm, trace.shape)
    except ReaderError as why:
        picked = f"no height pair: {why}"
    return {"format": afm.format, "channels": [c.summary() for c in afm.channels], "picked": picked,
            "error_signal": None if error is None else error[0].name}


def format_listing(afm: AfmFile) -> str:
    """A table of the channels (sizes in µm, line time in s) and the height pair line."""
    listing = channel_listing(afm)
    rows = [("name", "direction", "quantity", "unit", "lines×pixels", "size x×y (µm)", "line time (s)")]
    for c in listing["channels"]:
        time = "—" if c["line_time_s"] is None else f"{c['line_time_s']:.4g}"
        rows.append((c["name"], c["direction"] or "—", c["quantity"], c["unit"] or "—", "×".join(map(str, c["shape"])),
                     f"{c['size_m'][0] * 1e6:.4g}×{c['size_m'][1] * 1e6:.4g}", time))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = [f"{afm.path.name}: {afm.format}, {len(afm.channels)} channels"]
    lines += ["  " + "  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in rows]
    lines.append(listing["picked"])
    if listing["error_signal"] is not None:
        lines.append(f"Z loop's error signal: '{listing['error_signal']}' (diagnose reads the gap against it)")
    return "\n".join(lines)
