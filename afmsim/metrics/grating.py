"""Line edges, widths and periods of a 1-D grating imaged along the fast (x) axis (paper §3.4).

The paper observes, without compensation, a trace "pitch" of 3.6 µm on the left of the field vs
3.2 µm on the right, mirrored in the retrace — the fingerprint of the hysteretic x-stage
stretching one side of the scan and compressing the other.

Method: average the rows (scan lines) into one profile along x, threshold it at mid-height
``(P2 + P98)/2`` of the profile, and locate each crossing with linear interpolation between the
two bracketing pixels (sub-pixel). A Schmitt trigger (±10 % of the profile amplitude around the
mid level) decides when the profile has really changed state, so noise that wiggles around the
level near an edge yields one edge, not several.

Definitions (positions in metres, pixel centre ``l`` at ``origin_x + l·dx``):

* rising edge: low → high crossing going +x; falling edge: high → low.
* line width: from a rising edge to the next falling edge (the raised line's width at
  mid-height); its position is the midpoint of the two edges.
* period: spacing between consecutive rising edges; its position is their midpoint.

The images must be stored left → right (a retrace flipped back to the trace orientation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._grid import as_image, as_pixel_size

__all__ = ["GratingLines", "grating_profile", "line_pitches", "left_right_pitch"]


@dataclass(frozen=True)
class GratingLines:
    """Edges and derived lengths of a grating profile, all in metres.

    ``widths_m[i]`` is centred at ``width_centres_m[i]``; ``pitches_m[i]`` (rising-to-rising
    period) at ``pitch_centres_m[i]``. ``level`` is the mid-height threshold (image units) and
    ``x_mid_m`` the centre of the field, which splits it into left and right halves.
    """

    rising_m: np.ndarray
    falling_m: np.ndarray
    widths_m: np.ndarray
    width_centres_m: np.ndarray
    pitches_m: np.ndarray
    pitch_centres_m: np.ndarray
    level: float
    x_mid_m: float


def grating_profile(image, rows=None) -> np.ndarray:
    """Row-averaged height profile along x (optionally over a subset ``rows`` of scan lines)."""
    z = as_image(image, "image")
    if rows is not None:
        z = z[rows]
        if z.ndim == 1:
            z = z[None, :]
        if z.shape[0] == 0:
            raise ValueError("rows selects no scan line")
    return z.mean(axis=0)


def _edges_px(p: np.ndarray, level: float, band: float):
    """Sub-pixel rising/falling mid-level crossings (pixel units) with Schmitt hysteresis."""
    hi, lo = level + band, level - band
    rising, falling = [], []
    state = None  # unknown until the profile leaves the band
    for k, v in enumerate(p):
        if v >= hi and state != "high":
            if state == "low":
                j = k - 1
                while j > 0 and p[j] > level:
                    j -= 1  # last sample at/below the level before k
                rising.append(j + (level - p[j]) / (p[j + 1] - p[j]))
            state = "high"
        elif v <= lo and state != "low":
            if state == "high":
                j = k - 1
                while j > 0 and p[j] < level:
                    j -= 1
                falling.append(j + (level - p[j]) / (p[j + 1] - p[j]))
            state = "low"
    return np.asarray(rising, float), np.asarray(falling, float)


def line_pitches(image, pixel_size, *, rows=None, level: float | None = None,
                 band_fraction: float = 0.1, origin_x: float = 0.0) -> GratingLines:
    """Edges, line widths and rising-to-rising periods of a grating (see module doc).

    Parameters
    ----------
    image : 2-D array
        Heights (m); lines of the grating run along y (columns), so edges are along x.
    pixel_size : float or (dx, dy)
        Pixel pitch in metres (only dx is used).
    rows : slice or index array, optional
        Scan lines to average (default all).
    level : float, optional
        Edge threshold (image units); default mid-height ``(P2 + P98)/2`` of the profile.
    band_fraction : float
        Schmitt-trigger half-band as a fraction of ``P98 − P2``.
    origin_x : float
        x (m) of pixel column 0's centre.
    """
    dx, _ = as_pixel_size(pixel_size)
    p = grating_profile(image, rows)
    p2, p98 = np.percentile(p, [2.0, 98.0])
    amp = float(p98 - p2)
    if not amp > 0:
        raise ValueError("grating profile is flat: no lines to find")
    lev = 0.5 * float(p2 + p98) if level is None else float(level)
    r_px, f_px = _edges_px(p, lev, band_fraction * amp)
    rising = origin_x + r_px * dx
    falling = origin_x + f_px * dx
    widths, wc = [], []
    for r in rising:
        nxt = falling[falling > r]
        if nxt.size:
            widths.append(nxt[0] - r)
            wc.append(0.5 * (nxt[0] + r))
    pitches = np.diff(rising)
    pc = 0.5 * (rising[1:] + rising[:-1])
    x_mid = origin_x + 0.5 * (p.size - 1) * dx
    return GratingLines(rising, falling, np.asarray(widths), np.asarray(wc), pitches, pc,
                        lev, x_mid)


def left_right_pitch(image, pixel_size, *, quantity: str = "period", **kwargs):
    """Mean grating period (or line width) in the left vs the right half of the field.

    Definition: every complete period (consecutive rising edges; ``quantity="period"``, the
    default) or line width (rising → falling edge; ``quantity="width"``) is assigned to the
    half of the field containing its midpoint; the function returns the mean of each half.
    The paper's word "pitch" names the raised lines themselves, so its 3.6 / 3.2 µm may be
    either; both are offered. Extra keyword arguments go to :func:`line_pitches`.

    Returns
    -------
    (left_m, right_m)

    Raises
    ------
    ValueError
        If a half holds no complete period/width (field too small for the grating).
    """
    g = line_pitches(image, pixel_size, **kwargs)
    if quantity == "period":
        vals, pos = g.pitches_m, g.pitch_centres_m
    elif quantity == "width":
        vals, pos = g.widths_m, g.width_centres_m
    else:
        raise ValueError(f"quantity must be 'period' or 'width', got {quantity!r}")
    left = vals[pos < g.x_mid_m]
    right = vals[pos >= g.x_mid_m]
    for v, side in ((left, "left"), (right, "right")):
        if v.size == 0:
            raise ValueError(f"no complete {quantity} in the {side} half of the field")
    return float(left.mean()), float(right.mean())
