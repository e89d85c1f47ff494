"""Tip–sample contact: the imaged surface is the grey-scale dilation of the sample by the tip.

Villarrubia (J. Res. NIST 102, 425 (1997)): with the tip surface ``t(v) ≥ 0`` above its apex,
the apex height when the tip rests on the sample at lateral position x is

    I(x) = max_v [ S(x + v) − t(v) ] = max_u [ S(x − u) + b(u) ],   b(u) = −t(−u),

i.e. a grey-scale dilation ``S ⊕ b`` with the *reflected, negated* tip as the non-flat structuring
element (0 at the apex, negative away). This is computed with
``scipy.ndimage.grey_dilation(S, structure=b, footprint=…)``, which evaluates
``max_u [S(x − u) + b(u)]`` (checked by a unit test with an asymmetric tip). The inverse
operation, the certainty-limited reconstruction ``S_r = I ⊖ b``, is :func:`erode`.

Sampling: the tip is point-sampled at the sample's pixel offsets, so the result is the exact
dilation of the *sampled* sample by the *sampled* tip. Consequences:

* The footprint is cropped to tip heights ≤ the sample's height range (exact, see
  :func:`~afmsim.tip.shapes.tip_array`), so a 256² map with an MLCT tip costs ≈ 10–100 ms.
* If the pixel is coarser than the apex (``dx > R``, the normal case for an MLCT's 20 nm apex
  at 40–80 nm pixels) the apex curvature is not resolved: the nearest neighbours already sit on
  the cone flanks. Tip broadening of steep edges (``≈ h·tan α``) is still reproduced to ±1 pixel.
* Error vs the continuous dilation: the continuous maximiser v* is replaced by the best grid
  offset, ≤ half a pixel diagonal away; for smooth S and t the loss is second order,
  ≤ ½·(κ_S + κ_t)·(dx² + dy²)/4 (κ = max curvature), and never positive (discrete ≤ continuous)
  when S itself is exact at the pixel centres.
* Pixels near the map border see a sample extended by edge replication (``mode="nearest"``).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from afmsim.samples.heightmap import HeightMap

from .shapes import tip_array

__all__ = ["dilate", "erode", "structure_element", "sampling_info"]


def structure_element(tip, pixel_size, height_range=None, *, max_radius=None):
    """``(structure, footprint)`` for ``scipy.ndimage``: structure = −t reflected (b(u) = −t(−u))."""
    t, fp = tip_array(tip, pixel_size, height_range, max_radius=max_radius)
    return -t[::-1, ::-1], fp[::-1, ::-1]


def dilate(sample: HeightMap, tip, *, max_radius: float | None = None) -> HeightMap:
    """The surface an AFM with ``tip`` images on ``sample`` (apex height at each pixel) [m].

    Parameters
    ----------
    sample : HeightMap
        True topography [m].
    tip : ParabolicTip | ConeTip | ArrayTip
        See :mod:`afmsim.tip.shapes` (default MLCT: :func:`~afmsim.tip.shapes.mlct_tip`).
    max_radius : float, optional
        Hard cap on the tip footprint radius [m]; by default the footprint is cropped exactly to
        tip heights ≤ the sample's height range.
    """
    return _morphology(ndimage.grey_dilation, sample, tip, max_radius)


def erode(image: HeightMap, tip, *, max_radius: float | None = None) -> HeightMap:
    """Villarrubia's surface reconstruction ``I ⊖ b`` (upper bound of the true surface) [m]."""
    return _morphology(ndimage.grey_erosion, image, tip, max_radius)


def _morphology(operation, hmap: HeightMap, tip, max_radius) -> HeightMap:
    """Apply a scipy grey-scale morphology ``operation`` with the reflected tip as structure."""
    z = hmap.z
    b, fp = structure_element(tip, hmap.pixel_size, float(z.max() - z.min()), max_radius=max_radius)
    if b.size == 1:
        return hmap.with_z(z.copy())
    # the footprint mask excludes offsets that cannot matter; structure values there are ignored
    return hmap.with_z(operation(z, footprint=fp, structure=np.where(fp, b, 0.0), mode="nearest"))


def sampling_info(tip, pixel_size, height_range: float) -> dict:
    """How well the pixel grid resolves the tip: apex radius in pixels, footprint size, and the
    second-order discretisation bound ½·κ_t·(dx² + dy²)/4 of the tip part (κ_t = 1/R)."""
    dx, dy = (float(v) for v in np.broadcast_to(np.asarray(pixel_size, float), (2,)))
    R = getattr(tip, "apex_radius", None)
    t, fp = tip_array(tip, (dx, dy), height_range)
    return {
        "apex_radius_px": None if R is None else R / max(dx, dy),
        "apex_resolved": None if R is None else bool(max(dx, dy) <= R),
        "footprint_shape": t.shape,
        "footprint_pixels": int(fp.sum()),
        "tip_discretisation_bound_m": None if R is None else (dx * dx + dy * dy) / (8 * R),
    }
