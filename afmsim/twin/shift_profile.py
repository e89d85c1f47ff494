"""Trace/retrace shift profile: where along the fast axis the retrace shows a feature, relative to the trace.

For each of ``n_windows`` equal windows across the fast axis and each scan line, the x gradient of
the trace segment is matched against the retrace's gradient over a range of lags by normalised
cross-correlation; the best lag is refined to sub-pixel by a parabola through the peak and its
neighbours. A line counts in a window only where the trace has an edge there (gradient energy
above a fraction of the image's typical line energy) and the match is clear (peak correlation
≥ ``min_correlation``). The window's shift is the median over the counted lines; its standard error
is 1.2533·(1.4826·MAD)/√n (the median's asymptotic error for a normal spread).

A window holding features with different shifts reports the one that dominates its lines' best
matches (not their mean): the profile is sampled at the features, and windows should be narrow
against the profile's curvature.

Sign: ``shift = x_retrace − x_trace`` of the same feature, so a retrace that shows features to the
left gives a negative shift (the issue's convention).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = ["ShiftProfile", "shift_profile", "window_centres"]

MIN_LINES = 5
"""Fewest counted lines for a window's median to be reported (else NaN)."""


@dataclass(frozen=True)
class ShiftProfile:
    """Shift of the retrace against the trace per window (m; NaN where no line counted).

    ``per_line`` (lines, windows) holds each line's sub-pixel shift (m), NaN where it did not count.
    """

    x_m: np.ndarray
    shift_m: np.ndarray
    stderr_m: np.ndarray
    lines_used: np.ndarray
    per_line: np.ndarray

    def rows(self, which) -> "ShiftProfile":
        """The profile recomputed from the lines selected by ``which`` (a slice, mask or index array)."""
        return _summarise(self.x_m, self.per_line[which])


def window_centres(n_pixels: int, pixel_size_m: float, n_windows: int) -> np.ndarray:
    """x of the centres of ``n_windows`` equal windows across the fast axis (m, from the image's left edge)."""
    width = n_pixels * pixel_size_m
    return (np.arange(n_windows) + 0.5) * width / n_windows


def _summarise(x_m, per_line) -> ShiftProfile:
    used = np.sum(np.isfinite(per_line), axis=0)
    shift = np.full(per_line.shape[1], np.nan)
    err = np.full(per_line.shape[1], np.nan)
    for w in range(per_line.shape[1]):
        values = per_line[np.isfinite(per_line[:, w]), w]
        if values.size >= MIN_LINES:
            shift[w] = np.median(values)
            mad = 1.4826 * np.median(np.abs(values - shift[w]))
            err[w] = 1.2533 * max(mad, 1e-3 * abs(shift[w]) + 1e-12) / np.sqrt(values.size)
    return ShiftProfile(np.asarray(x_m), shift, err, used, per_line)


COMPETING_PEAK = 0.8
"""A correlation peak at least this fraction of the highest competes; the one nearest the reference lag wins."""


def _preferred_peak(curve: np.ndarray, reference: int) -> int:
    """Index of the local maximum of ``curve`` nearest ``reference`` among those ≥ COMPETING_PEAK × the highest.

    A sample periodic along x (a grating) correlates as well one period away: the reference (zero
    lag for the whole image, the image's lag for a window) decides between such aliases.
    """
    finite = np.where(np.isfinite(curve), curve, -np.inf)
    top = float(np.max(finite))
    k = np.arange(1, finite.size - 1)
    peaks = k[(finite[1:-1] >= finite[:-2]) & (finite[1:-1] >= finite[2:]) & (finite[1:-1] >= COMPETING_PEAK * top)]
    if peaks.size == 0:
        return int(np.argmax(finite))
    return int(peaks[np.argmin(np.abs(peaks - reference))])


def shift_profile(trace, retrace, pixel_size_m: float, n_windows: int = 8, max_shift_fraction: float = 0.2,
                  window_search_fraction: float = 0.1, line_search_fraction: float = 0.03,
                  min_correlation: float = 0.5) -> ShiftProfile:
    """Per-window median shift of ``retrace`` against ``trace`` (both (lines, pixels), left → right).

    Three stages, each searching near the last: the normalised cross-correlation of the x
    gradients summed over every line and window (a whole-image registration along x) gives the
    image's lag within ±``max_shift_fraction`` of the line; each window's correlation summed over
    its lines (a strip registration) gives the window's lag within ±``window_search_fraction`` of
    the line around it; each line's own peak is sought within ±``line_search_fraction`` (at least
    3 pixels) around that. Where peaks compete (≥ :data:`COMPETING_PEAK` × the highest: a sample
    periodic along x), the one nearest zero lag wins for the image, nearest the image's lag for a
    window — shifts beyond half the sample's period cannot be told from aliases.
    """
    t = np.asarray(trace, dtype=np.float64)
    r = np.asarray(retrace, dtype=np.float64)
    if t.shape != r.shape or t.ndim != 2:
        raise ValueError(f"trace and retrace must be 2-D images of one shape, got {t.shape} and {r.shape}")
    lines, pixels = t.shape
    if pixels < 2 * n_windows:
        raise ValueError(f"{pixels} pixels per line are too few for {n_windows} windows")
    gt = np.gradient(np.nan_to_num(t), axis=1)
    gr = np.gradient(np.nan_to_num(r), axis=1)
    max_lag = max(3, int(round(max_shift_fraction * pixels)))
    lags = np.arange(-max_lag, max_lag + 1)
    edges = np.linspace(0, pixels, n_windows + 1).round().astype(int)
    # zero gradient beyond the image: a lag past the edge matches against nothing there
    padded = np.pad(gr, ((0, 0), (max_lag, max_lag)))
    products, energy_c, energy_t = [], [], []
    for a, b in zip(edges[:-1], edges[1:]):
        seg_t = gt[:, a:b] - gt[:, a:b].mean(axis=1, keepdims=True)
        # retrace windows [a + lag, b + lag) for every lag: (lines, lags, width)
        cand = sliding_window_view(padded[:, a:b + 2 * max_lag], b - a, axis=1)
        cand = cand - cand.mean(axis=2, keepdims=True)
        products.append(np.einsum("lw,lkw->lk", seg_t, cand))
        energy_c.append(np.sum(cand * cand, axis=2))
        energy_t.append(np.sum(seg_t * seg_t, axis=1))
    products, energy_c, energy_t = np.array(products), np.array(energy_c), np.array(energy_t)

    def correlation(num, e_t, e_c):
        return num / np.sqrt(np.maximum(e_t * e_c, 1e-300))

    whole = correlation(products.sum(axis=(0, 1)), energy_t.sum(), energy_c.sum(axis=(0, 1)))
    image_lag = _preferred_peak(whole, int(np.flatnonzero(lags == 0)[0]))
    window_reach = max(3, int(round(window_search_fraction * pixels)))
    line_reach = max(3, int(round(line_search_fraction * pixels)))
    index = np.arange(lags.size)
    rows = np.arange(lines)
    energy_floor = 0.1 * np.median(np.sum(gt * gt, axis=1))
    per_line = np.full((lines, n_windows), np.nan)
    for w, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        strip = correlation(products[w].sum(axis=0), energy_t[w].sum(), energy_c[w].sum(axis=0))
        strip[np.abs(index - image_lag) > window_reach] = -np.inf
        centre = _preferred_peak(strip, image_lag)
        ncc = correlation(products[w], energy_t[w][:, None], energy_c[w])
        ncc[:, np.abs(index - centre) > line_reach] = -np.inf
        best = np.argmax(ncc, axis=1)
        peak = ncc[rows, best]
        inner = (best > 0) & (best < lags.size - 1) & (np.abs(best - centre) < line_reach)
        lo = ncc[rows, np.clip(best - 1, 0, lags.size - 1)]
        hi = ncc[rows, np.clip(best + 1, 0, lags.size - 1)]
        denom = lo - 2 * peak + hi
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(inner & (denom < 0), 0.5 * (lo - hi) / denom, 0.0)
        shift_px = lags[best] + np.clip(frac, -0.5, 0.5)
        energy = np.sum(gt[:, a:b] ** 2, axis=1) * pixels / (b - a)
        ok = inner & (peak >= min_correlation) & (energy >= energy_floor)
        per_line[ok, w] = shift_px[ok] * pixel_size_m
    return _summarise(window_centres(pixels, pixel_size_m, n_windows), per_line)
