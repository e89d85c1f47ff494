"""Image metrics for trace/retrace comparison (DIAPI-AFM paper §3.3–3.4).

* :mod:`.nsl2` — binarisation at the mean, NSL2 (eq. 8), e_D (eq. 9).
* :mod:`.registration` — sub-pixel trace/retrace shift.
* :mod:`.lenses` — micro-lens centres and trace/retrace pairing.
* :mod:`.grating` — grating edges, line widths, periods, left vs right of the field.
* :mod:`.scale` — magnification of the image along the fast axis.
* :mod:`.summary` — mean / sample σ over repeated experiments.

Images are 2-D arrays, rows = scan lines (y), columns = pixels left → right (x), heights in
metres; pixel sizes (m) are passed explicitly, as a scalar or ``(dx, dy)``.
"""

from .grating import GratingLines, grating_profile, left_right_pitch, line_pitches
from .lenses import lens_centres, match_centres
from .nsl2 import binarize, e_D, nsl2, nsl2_binarized
from .registration import image_shift, image_shift_px
from .scale import scale_x
from .summary import summarize

__all__ = [
    "binarize", "nsl2", "nsl2_binarized", "e_D",
    "image_shift", "image_shift_px",
    "lens_centres", "match_centres",
    "GratingLines", "grating_profile", "line_pitches", "left_right_pitch",
    "scale_x", "summarize",
]
