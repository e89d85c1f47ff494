"""Cross-coupling x → y read off the undriven axis of a loop record.

A loop record drives one axis (``v_V`` is the x drive). When it also has ``y_m``, the y axis was
not driven, so whatever of x the y sensor sees is x → y cross-coupling (flexure parasitic motion,
sensor cross-talk, a sample or sensor rotated by an angle κ ≈ tan θ). It is estimated as

    y_m ≈ κ · x_m + a + b · t        (least squares on the first ``train`` part; the offset and a
                                     linear drift of the y sensor are nuisance terms)

and checked on the held-out rest: the held-out RMS of y with and without κ·x. κ's standard error is
the ordinary least-squares one inflated for correlated residuals (lag-1 autocorrelation ρ:
n_eff = n(1 − ρ)/(1 + ρ)). κ is *detected* when it is ≥ 3 standard errors from 0 and shrinks the
held-out y RMS by ≥ 10 %; a detected κ outside the plausible range of
:data:`afmsim.diagnosis.plausible.PLAUSIBLE` (|κ| ≤ 5 %) is reported as implausible — a sign that
y moves with x through something else (a y drive that was not held, a mislabelled column).

Not modelled: a hysteretic or rate-dependent coupling (κ is one number for both branches).
"""

from __future__ import annotations

import numpy as np

from ..engine import rms
from ..plausible import implausible

__all__ = ["coupling_output", "coupling_text", "DETECTION_SIGMAS", "MIN_SHRINK"]

DETECTION_SIGMAS = 3.0
MIN_SHRINK = 0.10



def coupling_output(t, x, y, train) -> dict:
    """κ of x → y cross-coupling from a record whose y axis was not driven (see the module docstring).

    ``t`` (s), ``x``, ``y`` (m) are the record's samples, ``train`` a boolean mask of the fitting
    part. Returns the ``cross_coupling_output`` block of ``diagnosis.json``.
    """
    t, x, y = (np.asarray(a, dtype=np.float64) for a in (t, x, y))
    train = np.asarray(train, dtype=bool)
    held = ~train
    tc = t - t[train].mean()
    design = np.column_stack([x, np.ones_like(x), tc])
    coef, *_ = np.linalg.lstsq(design[train], y[train], rcond=None)
    kappa = float(coef[0])
    residual = y[train] - design[train] @ coef
    rho = float(np.clip(np.corrcoef(residual[:-1], residual[1:])[0, 1], 0.0, 0.999)) if residual.size > 2 else 0.0
    n_eff = max(residual.size * (1 - rho) / (1 + rho), 4.0)
    cov = np.linalg.pinv(design[train].T @ design[train]) * residual.var() * residual.size / n_eff
    kappa_se = float(np.sqrt(max(cov[0, 0], 0.0)))
    # held-out: y with only its nuisance terms (refitted on the training part) vs with κ·x too
    nuisance, *_ = np.linalg.lstsq(design[train][:, 1:], y[train], rcond=None)
    rms_without = rms(y[held] - design[held][:, 1:] @ nuisance)
    rms_with = rms(y[held] - design[held] @ coef)
    shrink = 1.0 - rms_with / rms_without if rms_without > 0 else 0.0
    detected = abs(kappa) >= DETECTION_SIGMAS * kappa_se and shrink >= MIN_SHRINK
    flags = implausible("cross_coupling", {"coefficient": kappa}) if detected else []
    return {"kappa": kappa, "kappa_se": kappa_se, "unit": "1 (m of y per m of x)",
            "heldout_rms_y_without_m": rms_without, "heldout_rms_y_with_m": rms_with, "heldout_shrink": shrink,
            "detected": bool(detected), "implausible": flags,
            "model": "y_m = kappa * x_m + a + b * t (y not driven), fitted on the training part"}


def coupling_text(block: dict) -> str:
    """One summary line for a ``cross_coupling_output`` block."""
    head = (f"κ = {100 * block['kappa']:+.3f} % ± {100 * block['kappa_se']:.3f} % (y not driven; held-out y RMS "
            f"{block['heldout_rms_y_without_m'] * 1e9:.1f} → {block['heldout_rms_y_with_m'] * 1e9:.1f} nm)")
    if not block["detected"]:
        return head + ": not detected."
    if block["implausible"]:
        return head + ": IMPLAUSIBLE for stage cross-coupling (|κ| ≤ 5 %); y follows x through something else."
    return head + ": y follows x."
