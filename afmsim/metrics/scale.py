"""Scale (magnification) error of a scanned image along the fast axis.

A stage that covers less than the intended range stretches every feature in the image: an image
whose pixels were meant to span 2–32 µm while the tip really travelled 1.5–25.3 µm shows the
sample magnified 30 / 23.8 = 1.26×. The simulator knows where the tip was (the mean actual x over
each pixel, :class:`afmsim.scan.ScanImages`), so the magnification is measured exactly rather
than estimated from a feature spacing (the default micro-lens scans hold one whole lens per row,
too few for a spacing).
"""

from __future__ import annotations

import numpy as np

__all__ = ["scale_x"]


def scale_x(intended_x_m, actual_x_trace_m, actual_x_retrace_m) -> float:
    """Magnification along x: intended span of the pixel centres over the span the tip travelled.

    Parameters
    ----------
    intended_x_m : 1-D array
        Intended x (m) of the pixel centres, left → right.
    actual_x_trace_m, actual_x_retrace_m : 2-D arrays (lines, pixels)
        Mean actual x (m) of the tip over each pixel of the trace and retrace, left → right.

    Returns
    -------
    float
        ``(x_last − x_first) / median over lines and both directions of (actual_last − actual_first)``:
        1 is true scale, 1.26 shows features 26 % too wide, 0.9 10 % too narrow.
    """
    x = np.asarray(intended_x_m, dtype=np.float64)
    spans = np.concatenate([np.asarray(a, dtype=np.float64)[:, -1] - np.asarray(a, dtype=np.float64)[:, 0]
                            for a in (actual_x_trace_m, actual_x_retrace_m)])
    travelled = float(np.median(spans))
    if x.size < 2 or not travelled > 0:
        raise ValueError("scale_x needs at least two pixels and a tip that moved to +x")
    return float((x[-1] - x[0]) / travelled)
