"""AFM tip shapes (MLCT defaults) and tip–sample contact by grey-scale dilation (Villarrubia).

See :mod:`afmsim.tip.shapes` (height functions, sampling on the pixel grid) and
:mod:`afmsim.tip.dilation` (:func:`dilate`, :func:`erode`, sign conventions, sampling limits).
"""

from .shapes import (
    MLCT_APEX_RADIUS,
    MLCT_HALF_ANGLE_DEG,
    ArrayTip,
    ConeTip,
    ParabolicTip,
    mlct_tip,
    tip_array,
)
from .dilation import dilate, erode, sampling_info, structure_element

__all__ = [
    "ParabolicTip",
    "ConeTip",
    "ArrayTip",
    "mlct_tip",
    "tip_array",
    "MLCT_APEX_RADIUS",
    "MLCT_HALF_ANGLE_DEG",
    "dilate",
    "erode",
    "structure_element",
    "sampling_info",
]
