"""The loop front of the diagnosis: measured loop records (``t_s, v_V, x_m`` [, ``y_m``]).

Its modules, in the order a record passes through them, are listed in :mod:`afmsim.diagnosis`;
the attribution itself is the shared :mod:`afmsim.diagnosis.engine`.
"""

from .attribute import diagnose_loops, diagnose_record
from .record import LoopRecord, load_record
from .open_world import validate_open_world
from .validation import validate_diagnosis

__all__ = ["diagnose_loops", "diagnose_record", "validate_diagnosis", "validate_open_world", "load_record", "LoopRecord"]
