"""The image front of the diagnosis: measured trace/retrace images (``.npz``, ``.gwy``, vendor files).

Its modules, in the order a scan passes through them, are listed in :mod:`afmsim.diagnosis`;
the attribution itself is the shared :mod:`afmsim.diagnosis.engine`.
"""

from .attribute import diagnose_image_record, diagnose_images
from .record import ImageRecord, load_images
from .validation import validate_image_diagnosis

__all__ = ["diagnose_images", "diagnose_image_record", "validate_image_diagnosis", "load_images", "ImageRecord"]
