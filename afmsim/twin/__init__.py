"""A virtual twin of a real AFM: calibrate afmsim's instrument from its own images and loop records, then predict.

    from afmsim.twin import calibrate, predict
    calibrate("circles.nid", "twin")                                # twin/instrument.yaml, calibration.json, .png
    predict("twin/instrument.yaml", "squares_holes.nid", "pred")   # pred/prediction.json, prediction.png

Pipeline: :mod:`.measured` (vendor file → trace/retrace via :mod:`afmsim.readers`) → :mod:`.shift_profile`
(where the retrace shows each feature) → :mod:`.raster` + :mod:`.simulate` (the real raster on a twin) →
:mod:`.calibrate_images` / :mod:`.calibrate_loops` (fits) → :mod:`.instrument` (``instrument.yaml``, the
twin's stage) → :mod:`.predict_images` → :mod:`.figures`; :mod:`.workflow` writes the run folders.
"""

from .instrument import Instrument, InstrumentError, build_twin_stage, load_instrument
from .workflow import calibrate, predict

__all__ = ["calibrate", "predict", "Instrument", "InstrumentError", "load_instrument", "build_twin_stage"]
