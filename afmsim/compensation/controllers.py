"""Open-loop feedforward controllers for the XY stage (paper Figure 1).

A controller maps the intended displacement of one axis (m) to its drive voltage (V). Kinds:

* ``none`` — the nominal linear sensitivity, v = d / S_nominal (what an uncalibrated stage does);
* ``spi``, ``diapi``, ``iiapi`` and the better model — an inverse model from
  :data:`afmsim.hysteresis.MODELS`, identified on the stage's own identification experiment;
* ``vendor`` — a memoryless polynomial linearisation per scan direction, fitted to the rising and
  falling branches of the identification loop: the open-loop "linearisation" that commercial
  AFMs ship (the analogue of the paper's Bruker reference, column D_B);
* ``ideal`` — ``none`` on a stage without piezo memory (no hysteresis, no creep), everything else
  equal (:func:`afmsim.experiment.ideal_twin` builds it): the floor that no compensation can beat.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from afmsim.hysteresis import MODELS
from afmsim.hysteresis.fitting import branch_signs, check_fit_inputs

__all__ = ["CONTROLLER_NAMES", "NominalLinear", "VendorLinearisation", "build_controller"]


@dataclass(frozen=True)
class NominalLinear:
    """v = d / S: the uncompensated drive, S in m/V."""

    sensitivity_m_per_V: float
    name = "none"

    def predict(self, displacement) -> np.ndarray:
        return np.asarray(displacement, dtype=np.float64) / self.sensitivity_m_per_V


@dataclass(frozen=True, eq=False)
class VendorLinearisation:
    """Memoryless per-direction polynomial v = p_trace(d) or p_retrace(d) (coefficients, V/mᵏ).

    The branch follows the sign of the displacement increment, as in DIAPI; unlike an operator
    model it has no memory of where the last reversal happened, so it is exact only on the loop
    it was calibrated on.
    """

    trace: np.polynomial.Polynomial
    retrace: np.polynomial.Polynomial
    name = "vendor"

    @classmethod
    def fit(cls, displacement, voltage, degree: int = 3) -> "VendorLinearisation":
        d, v = check_fit_inputs(displacement, voltage, 2 * (degree + 1))
        rising = branch_signs(d) > 0
        fits = [np.polynomial.Polynomial.fit(d[mask], v[mask], degree) for mask in (rising, ~rising)]
        return cls(*fits)

    def predict(self, displacement) -> np.ndarray:
        d = np.asarray(displacement, dtype=np.float64)
        return np.where(branch_signs(d) > 0, self.trace(d), self.retrace(d))


#: Controller names accepted by scenarios, in the order results are reported.
CONTROLLER_NAMES = ("none", "spi", "diapi", "iiapi", *[m for m in MODELS if m not in ("spi", "diapi", "iiapi")],
                    "vendor", "ideal")

def build_controller(name: str, displacement, voltage, *, nominal_sensitivity_m_per_V: float, n_operators: int = 10):
    """Identify the controller ``name`` for one axis from an identification record (m, V).

    ``none`` and ``ideal`` ignore the record and use the nominal sensitivity.
    """
    if name in ("none", "ideal"):
        return NominalLinear(nominal_sensitivity_m_per_V)
    if name == "vendor":
        return VendorLinearisation.fit(displacement, voltage)
    if name in MODELS:
        return MODELS[name].fit(displacement, voltage, n_operators=n_operators)
    raise ValueError(f"controller must be one of {CONTROLLER_NAMES}, got {name!r}")
