"""Simulated XY piezo nanopositioning stage — the plant that the hysteresis compensators drive.

Quick use::

    from afmsim.stage import default_stage, identification_experiment
    stage = default_stage()                      # asymmetric-Preisach plant, all physics on
    x, y = stage.move(t, vx, vy)                 # true positions (m) for drive voltages (V)
    xm = stage.x.measure(x, rng)                 # capacitive-sensor reading (rng: numpy Generator)
    ideal = stage.hysteresis_free()              # same plant, hysteresis → nominal sensitivity
    quiet = stage.with_effects(creep=False, noise=False, coupling=False)

The plant's hysteresis deliberately comes from a different family (Preisach or Duhem) than the
Prandtl–Ishlinskii compensators of :mod:`afmsim.hysteresis` (no inverse crime).
"""

from .axis import AxisParams, PiezoAxis, creep_bank
from .hysteresis_models import (HYSTERESIS_MODELS, AsymmetricDuhem, AsymmetricPreisach, HysteresisModel,
                                LinearHysteresis)
from .stage import IdentificationRecord, XYStage, default_stage, identification_experiment, triangle_wave

__all__ = ["AxisParams", "PiezoAxis", "XYStage", "default_stage", "triangle_wave", "identification_experiment",
           "IdentificationRecord", "HysteresisModel", "AsymmetricPreisach", "AsymmetricDuhem",
           "LinearHysteresis", "HYSTERESIS_MODELS", "creep_bank"]
