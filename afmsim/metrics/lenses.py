"""Micro-lens centre positions in a height image (paper §3.3, Figures 10–13).

Method: threshold the image (default: Otsu's threshold), label the connected regions above it
(8-connectivity), and take each region's centroid weighted by ``height − threshold``. The
weights fall continuously to zero at the region boundary, so the pixelated outline does not
bias the centre: on synthetic spherical caps of ≥ 5 px radius the error is ≪ 0.1 px.

Assumes a levelled image (lenses above a roughly flat background); level/plane-fit first
otherwise. Regions touching the image border are dropped by default, because a cut lens has a
biased centroid.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from skimage.filters import threshold_otsu
from skimage.measure import label, regionprops

from ._grid import as_image, as_pixel_size

__all__ = ["lens_centres", "match_centres"]


def lens_centres(image, pixel_size, *, threshold: float | None = None, min_area_px: int = 9,
                 exclude_border: bool = True, origin=(0.0, 0.0)) -> np.ndarray:
    """Centres of the lenses (bright/raised blobs) in ``image``.

    Parameters
    ----------
    image : 2-D array
        Heights (m); rows = y scan lines, columns = x pixels left → right.
    pixel_size : float or (dx, dy)
        Pixel pitch in metres.
    threshold : float, optional
        Height (m) separating lens from background; default Otsu's threshold of the image.
    min_area_px : int
        Regions with fewer pixels are ignored (noise specks).
    exclude_border : bool
        Drop regions touching the image border (default True).
    origin : (x0, y0)
        Position (m) of the centre of pixel ``[0, 0]`` (same convention as ``HeightMap``).

    Returns
    -------
    ndarray, shape (k, 2)
        ``(x, y)`` of each centre in metres, sorted by y then x. ``k`` may be 0.
    """
    z = as_image(image, "image")
    dx, dy = as_pixel_size(pixel_size)
    x0, y0 = (float(v) for v in origin)
    if np.ptp(z) == 0.0:
        return np.empty((0, 2))
    t = float(threshold_otsu(z)) if threshold is None else float(threshold)
    mask = z > t
    weights = np.where(mask, z - t, 0.0)
    labels = label(mask, connectivity=2)
    ny, nx = z.shape
    out = []
    for reg in regionprops(labels, intensity_image=weights):
        if reg.area < min_area_px:
            continue
        r0, c0, r1, c1 = reg.bbox
        if exclude_border and (r0 == 0 or c0 == 0 or r1 == ny or c1 == nx):
            continue
        row, col = reg.centroid_weighted
        out.append((x0 + col * dx, y0 + row * dy))
    if not out:
        return np.empty((0, 2))
    arr = np.asarray(out, dtype=np.float64)
    return arr[np.lexsort((arr[:, 0], arr[:, 1]))]


def match_centres(a, b, max_distance: float | None = None):
    """Pair two centre lists (e.g. trace vs retrace) by minimum total distance.

    Parameters
    ----------
    a, b : array_like, shape (k_a, 2), (k_b, 2)
        ``(x, y)`` positions in metres.
    max_distance : float, optional
        Pairs further apart than this (m) are dropped.

    Returns
    -------
    (ia, ib, displacement)
        Index arrays into ``a`` and ``b`` and ``b[ib] − a[ia]`` (shape (m, 2), metres).
    """
    a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 2)
    if len(a) == 0 or len(b) == 0:
        return np.empty(0, int), np.empty(0, int), np.empty((0, 2))
    cost = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    ia, ib = linear_sum_assignment(cost)
    if max_distance is not None:
        keep = cost[ia, ib] <= max_distance
        ia, ib = ia[keep], ib[keep]
    return ia, ib, b[ib] - a[ia]
