"""Which channel of a file is the topography, and its trace/retrace pair.

Preference among the length (m) channels that hold both scan directions, first in file order
within a rank:

0. the Z drive / topography (``Topography``, ``Height``, ``Z-Axis``, ``Z``): what the Z loop
   commands, which is what ``afmsim`` records as height (:mod:`afmsim.scan.zloop`);
1. a Z position sensor (``Z-Axis Sensor``, ``ZSensor``, ``Height Sensor``, JPK's ``Height (measured)``):
   the true height, but
   not what the simulated instrument records;
2. any other length channel the vendor did not name as deflection, amplitude, …

Second-pass (lift/interleave, Nanosurf "2nd scan") channels are never picked unless named.

:func:`pick_error_pair` finds the Z loop's error signal beside the height: a channel the vendor
names an error (``Amplitude Error``, ``Peak Force Error``, ``Error Signal``), else the oscillation
amplitude (dynamic mode: the Z loop holds it at its setpoint), else the deflection (contact mode:
likewise) — both directions, the height's pixel grid, no second pass.
"""

from __future__ import annotations

import re

from .channels import RETRACE_DIRECTIONS, TRACE_DIRECTIONS, AfmFile, Channel, ReaderError

__all__ = ["pick_height_pair", "pick_error_pair"]

_REASONS = ("the Z drive/topography, what afmsim records as height", "a Z position sensor, the best height "
            "channel with both directions", "a length channel with both directions (no better-named height)")


def _rank(channel: Channel) -> int | None:
    low = channel.name.lower()
    if channel.quantity != "height" or channel.unit != "m" or re.search(r"2nd|lift|interleave|nap", low):
        return None
    if re.search(r"sensor|sens\b|measured", low):
        return 1
    if re.search(r"topo|height|z[-_ ]?axis|z[-_ ]?piezo|^z\b", low):
        return 0
    return 2


def _pairs(channels) -> dict[str, dict[str, Channel]]:
    """``{name: {"trace": channel, "retrace": channel}}`` (either may be missing), file order."""
    out: dict[str, dict[str, Channel]] = {}
    for channel in channels:
        side = "trace" if channel.direction in TRACE_DIRECTIONS else \
            "retrace" if channel.direction in RETRACE_DIRECTIONS else None
        if side is not None:
            out.setdefault(channel.name, {}).setdefault(side, channel)
    return out


def _one_direction(name: str, pair: dict, fmt: str) -> str:
    have = next(iter(pair.values())).direction
    hint = "; Park writes one direction per file: give the other file too (--retrace)" if fmt == "park" else ""
    return f"'{name}' has the {have} scan only; the diagnosis needs both directions (trace and retrace){hint}"


def pick_height_pair(afm: AfmFile, channel: str | None = None) -> tuple[Channel, Channel, str]:
    """``(trace, retrace, description)``: the height channel's forward and backward scans.

    ``channel`` (the vendor's name, case-insensitive) overrides the choice. Raises
    :class:`ReaderError` with one line when the file has one direction only or no height channel.
    """
    label = afm.path.name
    pairs = _pairs(afm.channels)
    names = list(dict.fromkeys(c.name for c in afm.channels))
    if channel is not None:
        match = [n for n in pairs if n.lower() == channel.strip().lower()]
        if not match:
            raise ReaderError(f"{label}: no channel '{channel}' with a scan direction; channels: {names}")
        pair = pairs[match[0]]
        if len(pair) < 2:
            raise ReaderError(f"{label}: {_one_direction(match[0], pair, afm.format)}")
        if pair["trace"].unit != "m":
            raise ReaderError(f"{label}: channel '{match[0]}' is in '{pair['trace'].unit}', not a height in m")
        chosen, reason = match[0], "named by --channel"
    else:
        heights = {n: p for n, p in pairs.items() if _rank(next(iter(p.values()))) is not None}
        both = {n: p for n, p in heights.items() if len(p) == 2}
        if not both:
            if heights:
                name, pair = next(iter(heights.items()))
                raise ReaderError(f"{label}: {_one_direction(name, pair, afm.format)}")
            raise ReaderError(f"{label}: no height channel (a length in m with a scan direction) among {names}; "
                              "name one with --channel")
        chosen = min(both, key=lambda n: _rank(both[n]["trace"]))
        reason = _REASONS[_rank(both[chosen]["trace"])]
        pair = both[chosen]
    trace, retrace = pair["trace"], pair["retrace"]
    if trace.shape != retrace.shape:
        raise ReaderError(f"{label}: '{chosen}' {trace.direction} and {retrace.direction} shapes differ: "
                          f"{trace.shape} vs {retrace.shape}")
    if not all(abs(a - b) <= 1e-6 * max(abs(a), abs(b)) for a, b in zip(trace.size_m, retrace.size_m)):
        raise ReaderError(f"{label}: '{chosen}' {trace.direction} and {retrace.direction} scan sizes differ: "
                          f"{[f'{v * 1e6:.4g}' for v in trace.size_m]} vs "
                          f"{[f'{v * 1e6:.4g}' for v in retrace.size_m]} µm (not one scan's two directions)")
    others = [n for n in pairs if n != chosen and _rank(next(iter(pairs[n].values()))) is not None]
    also = f"; other height channels: {', '.join(others)}" if others else ""
    rotation = afm.metadata.get("scan_rotation_deg")
    turned = f"; scan frame rotated {rotation:g}° from the stage axes" if rotation else ""
    return trace, retrace, (f"{label}: picked '{chosen}' {trace.direction}/{retrace.direction} ({reason}{also}), "
                            f"{trace.shape[0]}×{trace.shape[1]} px{turned}")


def _error_rank(channel: Channel) -> int | None:
    low = channel.name.lower()
    if channel.quantity not in ("amplitude", "deflection") or re.search(r"2nd|lift|interleave|nap", low):
        return None
    if re.search(r"error", low):
        return 0
    return 1 if channel.quantity == "amplitude" else 2


def pick_error_pair(afm: AfmFile, shape: tuple[int, int]) -> tuple[Channel, Channel] | None:
    """``(trace, retrace)`` of the Z loop's error signal on a ``shape`` (lines, pixels) grid, or None.

    The feedback holds this signal at its setpoint wherever the tip follows the surface; where it
    departs, the recorded height is not the surface (edges taken faster than the loop can follow,
    the tip leaving the surface). Preference: a channel named an error, then an amplitude, then a
    deflection, first in file order within a rank.
    """
    best = None
    for name, pair in _pairs(afm.channels).items():
        if len(pair) < 2 or pair["trace"].shape != tuple(shape) or pair["retrace"].shape != tuple(shape):
            continue
        rank = _error_rank(pair["trace"])
        if rank is not None and (best is None or rank < best[0]):
            best = (rank, pair["trace"], pair["retrace"])
    return None if best is None else best[1:]
