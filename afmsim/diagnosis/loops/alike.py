"""What outside the loop candidate set does to a record what a candidate's fitted term does.

:meth:`.attribute.LoopFront.alike_outside` asks this of every candidate that passes the engine's
tests; a term that something outside the set can stand in for is reported and not named
(:func:`afmsim.diagnosis.engine.attribute`; docs/diagnosis.md, "A lag alone is not named" and
"A drift that scales with the displacement is not named").

* a ``dynamics`` term fitted as a lag alone, no resonance (:func:`lag_alone`,
  :data:`RATE_WIDTH_ALIKE`): a lag offsets a loop by −τ·ẋ, and a loop width that grows with the
  drive rate offsets it by a term proportional to the rate that builds up after a reversal as the
  loop's slope does — one record cannot tell the two apart;
* a ``drift`` whose slow change scales with the displacement (:func:`scales_with_displacement`,
  :data:`SENSITIVITY_ALIKE`): a sensor whose sensitivity changes by g(t) during the record reads
  ``(1 + g)·x``, a residual ``g(t)·x`` that an additive drift follows only through the mean
  displacement. Where the displacement times the drift's own time columns fits the record's
  residual decisively better than the drift alone, the drift term stands in for such a change.
"""

from __future__ import annotations

import numpy as np

from ..engine import training_delta_bic
from .model import drift_curvature_column

__all__ = ["RATE_WIDTH_ALIKE", "SENSITIVITY_ALIKE", "SENSITIVITY_DELTA_BIC", "lag_alone", "scales_with_displacement",
           "sensitivity_delta_bic"]

RATE_WIDTH_ALIKE = "a loop width that grows with the drive rate (rate-dependent hysteresis, not a candidate)"
SENSITIVITY_ALIKE = ("a change that scales with the displacement, as a sensor sensitivity that changes during the "
                     "record gives (not a candidate)")
#: ΔBIC (decorrelated samples) the displacement-scaled columns must reach for a drift to read as a
#: sensitivity change: "very strong" evidence on Kass & Raftery's scale (J. Am. Stat. Assoc. 90 (1995)
#: 773). Chosen on the spent open-world records of 40001–45003 with a drift named (development
#: records): the 22 with a true drift (alone or with a coupling) read −6.6 to +17 — the engine's bar
#: of −6 would have withheld one, a 90 nm/min drift on a scattered-Preisach stage under sines — and
#: the 12 sensitivity ramps (0.5 %, 2 %) −339 to +4.7, nine below −10 (those above: ramps the
#: record's scored samples barely see).
SENSITIVITY_DELTA_BIC = -10.0


def lag_alone(params: dict | None) -> bool:
    """True for a fitted ``dynamics`` term without a resonance (:data:`RATE_WIDTH_ALIKE`)."""
    return params is not None and "resonance_hz" not in params


def sensitivity_delta_bic(t, x, prediction, train, scored) -> float:
    """ΔBIC of a sensitivity change over the drift it looks like, on the ``scored`` samples.

    The residual ``x − prediction`` (m) of a model with the drift is regressed on an offset, the
    drift's time columns (``t`` normalised, its curvature column, :func:`.model.drift_curvature_column`
    with the training mask ``train``) and the normalised predicted displacement, then on those and
    the displacement times both time columns (2 parameters more). ``scored``: the training part and
    the scored held-out samples — the test looks for structure in the residual where the record has
    one, as the held-out significance test does; it fits no model that predicts.
    """
    t, x, prediction = (np.asarray(a, dtype=float) for a in (t, x, prediction))
    tn = (t - t[0]) / (t[-1] - t[0])
    time_cols = np.column_stack([tn, drift_curvature_column(tn, train)])[scored]
    p = prediction[scored]
    xs = (p - p.mean()) / (np.ptp(p) or 1.0)
    r = (x - prediction)[scored]
    plain = np.column_stack([np.ones(r.size), time_cols, xs])
    scaled = np.hstack([plain, xs[:, None] * time_cols])

    def remainder(columns):
        coef, *_ = np.linalg.lstsq(columns, r, rcond=None)
        return r - columns @ coef

    return training_delta_bic(remainder(plain), remainder(scaled), 2)


def scales_with_displacement(t, x, prediction, train, scored) -> bool:
    """True where a fitted drift's change scales with the displacement (:func:`sensitivity_delta_bic`
    below :data:`SENSITIVITY_DELTA_BIC`): :data:`SENSITIVITY_ALIKE`."""
    return sensitivity_delta_bic(t, x, prediction, train, scored) < SENSITIVITY_DELTA_BIC
