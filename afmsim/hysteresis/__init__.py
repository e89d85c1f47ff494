"""Piezo hysteresis: backlash operators and the inverse (displacement → voltage) models.

Every model in :data:`MODELS` shares one contract::

    model = MODELS[name].fit(displacement, voltage, n_operators=10)   # 1-D arrays, m and V
    voltage = model.predict(desired_displacement)                    # the feedforward

``predict`` always starts from the eq. (4) initial operator state.
"""

from .capi import CAPI
from .diapi import DIAPI
from .iiapi import IIAPI
from .operators import osp, osp_reference, play, play_reference
from .spi import SPI

MODELS = {"spi": SPI, "diapi": DIAPI, "iiapi": IIAPI, "capi": CAPI}

__all__ = ["osp", "play", "osp_reference", "play_reference", "SPI", "DIAPI", "IIAPI", "CAPI", "MODELS"]
