"""Calibrate a twin's axis from a loop record (``t_s,v_V,x_m[,y_m]``) and predict its held-out part.

The record's first :data:`TRAIN_FRACTION` of samples is fitted, the rest predicted. The drive is
mapped linearly onto the twin's 0–10 V (record minimum → 0 V, maximum → 10 V, a bipolar record
included); the twin axis is afmsim's plant (:func:`afmsim.twin.instrument.build_twin_axis`:
Preisach hysteresis, log-law creep, amplifier, resonance). Fitted by
:func:`scipy.optimize.least_squares`: the Preisach hysteretic fraction, relay-width scale and power,
skew and reversible curvature, the creep γ and the amplifier bandwidth (the dynamics: at loop
rates a first-order lag); travel, x offset and a linear drift enter linearly and are solved
exactly at every step (variable projection). Uncertainties: √diag((JᵀJ)⁻¹·χ²/dof).

The default stage is afmsim's default plant shape on the same drive map with its travel, offset
and drift fitted the same way on the same samples: it differs from the twin only in the parameters
calibrated here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from afmsim.diagnosis import load_record
from afmsim.diagnosis.engine import rms

from .instrument import AxisSpec, Instrument, LoopDriveSpec, build_twin_axis

__all__ = ["LoopCalibration", "calibrate_loop", "predict_loop", "TRAIN_FRACTION", "LOOP_FITTED"]

TRAIN_FRACTION = 0.6
"""Share of a loop record's samples that calibrates; the rest is predicted."""

LOOP_FITTED = {  # AxisSpec field -> (lower, upper, log-scaled)
    "hysteretic_fraction": (0.0, 1.0, False),
    "width_decay": (0.01, 5.0, True),
    "width_power": (0.0, 3.0, False),
    "skew": (-1.0, 1.0, False),
    "reversible_curvature": (-0.9, 5.0, False),
    "creep_gamma_per_decade": (0.0, 0.1, False),
    "amplifier_bandwidth_hz": (1.0, 1e6, True),
}
UM = 1e-6


@dataclass(frozen=True)
class LoopCalibration:
    instrument: Instrument
    report: dict
    fitted: list
    figure_data: tuple


def _drive(v, v_min, v_max):
    return 10.0 * (np.asarray(v) - v_min) / (v_max - v_min)


def _unit_response(spec: AxisSpec, t, u) -> np.ndarray:
    """Axis response (m per µm of travel) without drift and sensor noise."""
    axis = build_twin_axis(spec.model_copy(update={"travel_um": 1.0}))
    return axis.with_effects(drift=False, noise=False).move(t, u)


def _linear(columns, x, train):
    """Least-squares coefficients of ``x[train]`` on ``columns`` and their standard errors."""
    design = np.column_stack(columns)
    coef, *_ = np.linalg.lstsq(design[train], x[train], rcond=None)
    resid = x[train] - design[train] @ coef
    dof = max(1, int(train.sum()) - design.shape[1])
    cov = np.linalg.pinv(design[train].T @ design[train]) * (resid @ resid / dof)
    return coef, np.sqrt(np.clip(np.diag(cov), 0, None)), design @ coef


def _fit_linear(spec: AxisSpec, t, u, x, train):
    unit = _unit_response(spec, t, u)
    return _linear([unit, np.ones_like(t)], x, train)



def _split(n: int) -> np.ndarray:
    train = np.zeros(n, dtype=bool)
    train[: int(round(TRAIN_FRACTION * n))] = True
    return train


def _read(path):
    try:
        record = load_record(path)
    except ValueError as error:
        raise ValueError(" ".join(str(error).split())) from None
    if record.n < 50:
        raise ValueError(f"{path}: {record.n} samples; a loop record needs at least 50")
    return record


def calibrate_loop(path, max_nfev: int = 80) -> LoopCalibration:
    """Fit the twin axis to the first 60 % of the loop record at ``path`` and score the rest."""
    record = _read(path)
    t, v, x = record.t - record.t[0], record.v, record.x
    v_min, v_max = float(v.min()), float(v.max())
    if not v_max > v_min:
        raise ValueError(f"{path}: the drive v_V is constant; a loop record needs a varying drive")
    u = _drive(v, v_min, v_max)
    train = _split(t.size)
    base = AxisSpec()
    keys = list(LOOP_FITTED)
    lo = np.array([np.log(LOOP_FITTED[k][0]) if LOOP_FITTED[k][2] else LOOP_FITTED[k][0] for k in keys])
    hi = np.array([np.log(LOOP_FITTED[k][1]) if LOOP_FITTED[k][2] else LOOP_FITTED[k][1] for k in keys])

    def spec_of(theta) -> AxisSpec:
        values = {k: float(np.exp(th) if LOOP_FITTED[k][2] else th) for k, th in zip(keys, theta)}
        return base.model_copy(update=values)

    def residual(theta):  # in µm: least_squares' tolerances are absolute
        _, _, model = _fit_linear(spec_of(theta), t, u, x, train)
        return (model - x)[train] / UM

    theta0 = np.array([np.log(getattr(base, k)) if LOOP_FITTED[k][2] else getattr(base, k) for k in keys])
    best = least_squares(residual, theta0, bounds=(lo, hi), x_scale="jac", diff_step=1e-3, max_nfev=max_nfev)
    spec = spec_of(best.x)
    coef, coef_err, twin_x = _fit_linear(spec, t, u, x, train)
    dof = max(1, best.fun.size - best.x.size - 2)
    cov = np.linalg.pinv(best.jac.T @ best.jac) * (2 * best.cost / dof)  # θ units; residuals in µm
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    values = {k: getattr(spec, k) for k in keys}
    uncert = {k: float(values[k] * s if LOOP_FITTED[k][2] else s) for k, s in zip(keys, sd)}
    travel_um, offset_m = coef
    spec = spec.model_copy(update={"travel_um": float(np.clip(travel_um, 0.1, 1000))})
    instrument = Instrument(fast_axis=spec, loop_drive=LoopDriveSpec(v_min_V=v_min, v_max_V=v_max,
                                                                     x_offset_um=float(offset_m / UM)))
    _, _, default_x = _fit_linear(AxisSpec(), t, u, x, train)
    held = ~train
    parameters = {f"fast_axis.{k}": {"value": values[k], "uncertainty": uncert[k], "provenance": "fitted"} for k in keys}
    parameters["fast_axis.travel_um"] = {"value": float(travel_um), "uncertainty": float(coef_err[0]), "provenance": "fitted"}
    parameters["loop_drive.x_offset_um"] = {"value": float(offset_m / UM), "uncertainty": float(coef_err[1] / UM),
                                            "provenance": "fitted"}
    report = {
        "measured": str(path), "samples": int(t.size), "decimation": record.decimation,
        "train": f"first {TRAIN_FRACTION:.0%} of the samples (t ≤ {t[train][-1]:.4g} s)",
        "parameters": parameters,
        "drive_map": {"v_min_V": v_min, "v_max_V": v_max, "to": "0–10 V twin drive"},
        "fit": {"train_rms_m": rms((twin_x - x)[train]), "optimizer": best.message},
        "held_out": {"twin_rms_m": rms((twin_x - x)[held]), "default_stage_rms_m": rms((default_x - x)[held]),
                     "measured_rms_m": rms(x[held] - x[held].mean())},
        "not_constrained": ["slow_axis (one axis recorded)", "fast_axis.resonance_hz (above the record's band)",
                            "z_loop", "scan"],
    }
    fitted = [*(f"fast_axis.{k}" for k in keys), "fast_axis.travel_um",
              "loop_drive.v_min_V", "loop_drive.v_max_V", "loop_drive.x_offset_um"]
    figure_data = (t, v, x, {"twin": twin_x, "afmsim default stage": default_x}, int(train.sum()))
    return LoopCalibration(instrument, report, fitted, figure_data)


def predict_loop(instrument: Instrument, path) -> tuple[dict, tuple]:
    """Simulate the loop record at ``path`` on ``instrument``'s fast axis; score the last 40 %.

    The default stage's travel and offset are fitted on the first 60 % (see the module docstring).
    """
    if instrument.loop_drive is None:
        raise ValueError("instrument has no loop_drive block (it was not calibrated from a loop record); "
                         "predicting a loop record needs the record's drive map")
    record = _read(path)
    t, v, x = record.t - record.t[0], record.v, record.x
    drive = instrument.loop_drive
    u = _drive(v, drive.v_min_V, drive.v_max_V)
    twin_x = instrument.fast_axis.travel_um * _unit_response(instrument.fast_axis, t, u) + drive.x_offset_um * UM
    train = _split(t.size)
    _, _, default_x = _fit_linear(AxisSpec(), t, u, x, train)
    held = ~train
    twin_rms, default_rms = rms((twin_x - x)[held]), rms((default_x - x)[held])
    prediction = {"measured": str(path), "held_out": f"last {1 - TRAIN_FRACTION:.0%} of the samples",
                  "twin": {"held_out_rms_m": twin_rms},
                  "default_stage": {"held_out_rms_m": default_rms,
                                    "note": "afmsim's default plant shape; travel and offset fitted on the first 60 %"},
                  "twin_over_default_rms": twin_rms / default_rms if default_rms > 0 else None,
                  "measured_rms_m": rms(x[held] - x[held].mean())}
    return prediction, (t, v, x, {"twin": twin_x, "afmsim default stage": default_x}, int(train.sum()))
