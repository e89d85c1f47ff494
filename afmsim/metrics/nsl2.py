"""Trace/retrace dissimilarity: the normalised square L2 norm (NSL2) of the DIAPI-AFM paper.

Paper eq. (8)::

    D = Σ_i ((x_i − x̄)/σ_x − (y_i − ȳ)/σ_y)²,   σ = population standard deviation (1/n)

with x, y the trace and retrace images *after binarisation at each image's own mean grey
value*. Since both z-scored vectors have unit population variance, D = 2n(1 − r) with r the
Pearson correlation (for binarised images, the phi coefficient): 0 ≤ D ≤ 4n, D = 0 for
identical images, D = 4n for an image against its negative. D depends on n, so compare ratios
(D_N/D_A, e_D) with the paper, not raw values, unless the pixel count matches.

Paper eq. (9): e_D = (D_S − D_A)/D_S, the fractional NSL2 reduction of DIAPI over SPI.
"""

from __future__ import annotations

import numpy as np

from ._grid import as_image

__all__ = ["binarize", "nsl2", "nsl2_binarized", "e_D"]


def binarize(image) -> np.ndarray:
    """Binarise ``image`` at its own mean (paper, text of eq. 8).

    Returns a float64 array of the same shape with 1.0 where ``image > mean(image)`` and 0.0
    elsewhere (pixels exactly at the mean go to 0). A constant image therefore binarises to
    all zeros, for which NSL2 is undefined (``nsl2`` raises).
    """
    z = as_image(image, "image", min_size=1)
    return (z > z.mean()).astype(np.float64)


def _zscore(v: np.ndarray, name: str) -> np.ndarray:
    # Exact constancy check first: the mean of n identical floats may round, leaving a
    # spurious σ ~ 1e-17 that would make D meaningless rather than undefined.
    if np.ptp(v) == 0.0:
        raise ValueError(f"NSL2 is undefined: {name} is constant (σ = 0); "
                         f"every pixel equals {v.flat[0]!r}")
    sigma = v.std()  # population std (ddof=0), as in eq. (8)
    if not sigma > 0.0:
        raise ValueError(f"NSL2 is undefined: {name} has zero standard deviation")
    return (v - v.mean()) / sigma


def _nsl2(x, y, names: tuple[str, str]) -> float:
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    if xa.shape != ya.shape:
        raise ValueError(f"NSL2 needs images of the same shape: {names[0]} has {xa.shape}, "
                         f"{names[1]} has {ya.shape}")
    if xa.size < 2:
        raise ValueError(f"NSL2 needs at least 2 pixels, got {xa.size}")
    for v, n in zip((xa, ya), names):
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{n} contains NaN or inf")
    d = _zscore(xa.ravel(), names[0]) - _zscore(ya.ravel(), names[1])
    return float(np.dot(d, d))


def nsl2(x, y) -> float:
    """Paper eq. (8) on the values as given (no binarisation).

    Parameters
    ----------
    x, y : array_like, same shape
        First (e.g. trace) and second (e.g. retrace) image; any shape, flattened.

    Returns
    -------
    float
        D = Σ (z_x − z_y)², z = (v − mean)/σ with the population σ. Equals 2n(1 − r).

    Raises
    ------
    ValueError
        Shapes differ, non-finite values, or an image is constant (σ = 0: D undefined; the
        message names ``x`` or ``y``).
    """
    return _nsl2(x, y, ("x (first image)", "y (second image)"))


def nsl2_binarized(trace, retrace) -> float:
    """The paper's NSL2: binarise trace and retrace each at its own mean, then eq. (8).

    Raises ``ValueError`` naming ``trace``/``retrace`` if either binarises to a constant
    image (e.g. a flat scan) or the shapes differ.
    """
    t = as_image(trace, "trace", min_size=1)
    r = as_image(retrace, "retrace", min_size=1)
    if t.shape != r.shape:
        raise ValueError(f"NSL2 needs images of the same shape: trace has {t.shape}, "
                         f"retrace has {r.shape}")
    return _nsl2(binarize(t), binarize(r), ("trace (binarised at its mean)",
                                             "retrace (binarised at its mean)"))


def e_D(D_S, D_A):
    """Paper eq. (9): e_D = (D_S − D_A)/D_S as a fraction (0.443 ≙ the paper's 44.3 %).

    Works element-wise on arrays (one value per experiment) and returns a float for scalar
    input. Note the paper's "Mean" row of E_D is e_D of the *mean* D_S and D_A
    (``e_D(mean(D_S), mean(D_A))``), not the mean of the per-experiment e_D.

    Raises ``ValueError`` if any D_S is zero or any input is non-finite.
    """
    ds = np.asarray(D_S, dtype=np.float64)
    da = np.asarray(D_A, dtype=np.float64)
    if not (np.all(np.isfinite(ds)) and np.all(np.isfinite(da))):
        raise ValueError("e_D needs finite D_S and D_A")
    if np.any(ds == 0.0):
        raise ValueError("e_D is undefined for D_S = 0")
    out = (ds - da) / ds
    return float(out) if out.ndim == 0 else out
