"""Matplotlib height images of a run, on honest colour scales.

Conventions shared by every 2-D height image of a run (``figure_*.png``):

* heights are drawn **above the substrate**: each image's substrate level is the commonest level
  among its pixels below the image mean (the background that NSL2's binarization, eq. 8, also sees;
  for a grating the trench floor), see :func:`substrate_level`;
* one colour scale for the whole run: limits are the 0.1st and 99.9th percentiles of all the
  run's referenced trace/retrace heights (:func:`robust_limits`), never a fixed 0; pixels outside
  are drawn in the over/under colours (blue below, cyan above) and the colour bar's pointed ends
  say so;
* the trace − retrace difference (raw heights, nm) on a symmetric diverging scale whose limit is
  the 99.9th percentile of |difference| over every controller of the run, so the controllers'
  mismatches compare at a glance.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from afmsim.samples.heightmap import HeightMap  # noqa: E402

__all__ = ["FIXED_TITLES", "difference_cmap", "fixed_title_height", "height_extent_um", "substrate_level", "above_substrate", "robust_limits",
           "ColourScale", "run_colour_scales", "height_cmap", "show_height", "colour_extend", "PERCENTILES"]

UM, NM = 1e-6, 1e-9
#: Robust colour limits: these percentiles of the run's heights (the rest is drawn over/under).
PERCENTILES = (0.1, 99.9)
_UNDER, _OVER = "#1f4bff", "#00e5ff"


def height_extent_um(hmap: HeightMap) -> list[float]:
    """imshow extent (left, right, bottom, top) of a map's pixel edges, in µm."""
    dx, dy = hmap.pixel_size
    return [(hmap.x[0] - dx / 2) / UM, (hmap.x[-1] + dx / 2) / UM, (hmap.y[0] - dy / 2) / UM, (hmap.y[-1] + dy / 2) / UM]


def substrate_level(z: np.ndarray) -> float:
    """The substrate height of an image (same unit as ``z``): the most common level among the
    pixels below the image mean — the background that the NSL2 binarization (eq. 8, threshold =
    mean) sees. The median of the pixels in the fullest histogram bin (Freedman–Diaconis widths, at
    most 256 bins) is taken, not the median of all pixels below the mean: on a lens array those
    include the lens flanks and would put the flat substrate tens of nm below zero."""
    z = np.asarray(z, dtype=np.float64)
    below = z[z < z.mean()]
    if below.size == 0:
        return float(z.min())
    edges = np.histogram_bin_edges(below, bins="fd")
    if edges.size > 257:
        edges = np.linspace(below.min(), below.max(), 257)
    counts, edges = np.histogram(below, bins=edges)
    peak = int(np.argmax(counts))
    in_peak = below[(below >= edges[peak]) & (below <= edges[peak + 1])]
    return float(np.median(in_peak))


def above_substrate(hmap: HeightMap) -> HeightMap:
    """The map with its substrate level (:func:`substrate_level`) at 0."""
    return replace(hmap, z=hmap.z - substrate_level(hmap.z))


def robust_limits(arrays, percentiles=PERCENTILES) -> tuple[float, float]:
    """(low, high): the given percentiles of all values of ``arrays`` pooled (never a fixed 0)."""
    pooled = np.concatenate([np.ravel(a) for a in arrays])
    lo, hi = (float(v) for v in np.percentile(pooled, percentiles))
    if hi <= lo:
        hi = lo + max(abs(lo) * 1e-3, 1e-12)
    return lo, hi


@dataclass(frozen=True)
class ColourScale:
    """Height limits (nm, above substrate) and the trace − retrace limit (nm) of one run, and the
    ``extend`` of each colour bar (:func:`colour_extend` over every image of the run)."""

    height_nm: tuple[float, float]
    difference_nm: float
    height_extend: str = "neither"
    difference_extend: str = "neither"


def run_colour_scales(pairs: dict) -> ColourScale:
    """The run's colour scales from ``{controller: (trace, retrace)}`` (:mod:`module doc <afmsim.report.figures>`)."""
    heights = np.concatenate([above_substrate(m).z.ravel() / NM for pair in pairs.values() for m in pair])
    diffs = np.concatenate([(t.z - r.z).ravel() / NM for t, r in pairs.values()])
    limit = max(float(np.percentile(np.abs(diffs), PERCENTILES[1])), 1e-3)
    lo, hi = robust_limits([heights])
    return ColourScale((lo, hi), limit, colour_extend(heights, lo, hi), colour_extend(diffs, -limit, limit))


def height_cmap(name: str = "afmhot"):
    """A copy of ``name`` with the over/under colours of out-of-range pixels."""
    return plt.get_cmap(name).with_extremes(under=_UNDER, over=_OVER)


def colour_extend(values: np.ndarray, lo: float, hi: float) -> str:
    """The colour bar's ``extend``: a pointed end on each side that has values outside ``[lo, hi]``."""
    below, above = bool(np.any(values < lo)), bool(np.any(values > hi))
    return {(True, True): "both", (True, False): "min", (False, True): "max"}.get((below, above), "neither")


def show_height(ax, hmap: HeightMap, limits_nm) -> matplotlib.image.AxesImage:
    """Draw a map above its substrate (nm) on ``limits_nm``; axes in µm."""
    shown = ax.imshow(above_substrate(hmap).z / NM, origin="lower", extent=height_extent_um(hmap),
                      cmap=height_cmap(), vmin=limits_nm[0], vmax=limits_nm[1], interpolation="nearest")
    ax.set_xlabel("x (µm)")
    return shown


def difference_cmap():
    """The trace − retrace colour map: red where the trace is higher, with over/under colours."""
    return plt.get_cmap("RdBu_r").with_extremes(under="#301060", over="#602000")


#: Titles at a fixed height above their axes. By default matplotlib measures every tick label of
#: every axes at each draw to lift the titles clear of top-side ticks, which these figures do not
#: have: about a tenth of their drawing time.
FIXED_TITLES = {"axes.titley": 1.0}


def fixed_title_height(plot):
    """Make and draw ``plot``'s figure with :data:`FIXED_TITLES`."""
    @functools.wraps(plot)
    def drawn_with_fixed_titles(*args, **kwargs):
        with plt.rc_context(FIXED_TITLES):
            return plot(*args, **kwargs)
    return drawn_with_fixed_titles
