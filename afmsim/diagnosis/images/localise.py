"""Where is the held-out image gap? Shares of the squared, line-levelled residual.

Every entry gives ``share`` (fraction of Σr² over the held-out pixels) and ``sample_fraction``
(fraction of the held-out pixels), so ``share ≫ sample_fraction`` flags where the gap concentrates:

* ``direction`` — trace vs retrace (scenario reference only: the trace reference predicts the
  retrace alone);
* ``axis`` — ``slow``: the part of each held-out line's residual that a shift of the whole line
  along x explains (least squares on the model's x-gradient: misplaced lines — drift, creep,
  cross-coupling); ``fast``: the rest, structure within the line (mapping shape, Z lag, tip,
  turnaround dynamics);
* ``features`` — ``edges`` (the 20 % of pixels with the steepest measured x-slope, each direction's
  own: hysteresis puts the retrace's edges where the trace is flat) vs ``flats``;
* ``position`` — left / centre / right third of the line (the turnarounds are at the ends);
* ``time`` — first vs second half of the held-out lines (frame start: creep, approach transients);
* ``lines`` — ``worst``: the held-out lines (each direction its own) with the largest residual, 5 %
  of them (at least one): a gap in a few lines is an event in those lines — a tip jump, a particle
  picked up or dragged, a feedback glitch — that no stage or Z-loop term predicts;
* ``z_loop`` (only where the record carries the Z loop's error signal, an instrument's amplitude /
  deflection / error channel, or the deflection images of an ``afmsim run``) — the pixels where
  the loop was out of regulation (:func:`out_of_regulation`), each scored direction on its own
  error signal, which lies on the same pixels (the trace reference's own signal lies shifted by the
  stage's hysteresis and is not used). Where the signal is off its setpoint the recorded height is
  not the surface. A localisation, not a diagnosis: steep and curved parts of a sample put the
  loop off its setpoint and also carry most of any misplacement's gap, so a gap concentrated there
  does not single out the Z loop (on the simulator's own scans it concentrates there as often for
  creep, dynamics and tip cases as for a slow loop: docs/diagnosis.md, "The Z loop's error signal").
"""

from __future__ import annotations

import numpy as np

__all__ = ["localise_image", "out_of_regulation", "REGULATION_SIGMA"]

WORST_LINES = 0.05  # share of the held-out lines counted as the worst
#: Robust standard deviations of the error signal from its median beyond which the Z loop is out of
#: regulation: far outside the signal's own scatter while the loop holds its setpoint (what it flags on
#: the bundled real files: docs/diagnosis.md, "The Z loop's error signal").
REGULATION_SIGMA = 5.0


def out_of_regulation(error) -> np.ndarray | None:
    """Pixels (lines, pixels; bool) where the error signal lies more than :data:`REGULATION_SIGMA`
    robust σ from its median (the setpoint); None when the signal does not vary (no reading).
    Non-finite pixels count as in regulation."""
    e = np.asarray(error, dtype=float)
    finite = e[np.isfinite(e)]
    if finite.size == 0:
        return None
    centre = np.median(finite)
    sigma = 1.4826 * np.median(np.abs(finite - centre)) or float(np.std(finite))
    if sigma == 0:
        return None
    with np.errstate(invalid="ignore"):
        return np.abs(e - centre) > REGULATION_SIGMA * sigma


def _share(r2: np.ndarray, mask: np.ndarray, total: float) -> dict:
    return {"share": round(float(r2[mask].sum()) / total, 4), "sample_fraction": round(float(mask.mean()), 4)}


def localise_image(trace_res, retrace_res, trace_model, retrace_model, measured, held, *, with_trace=True,
                   error=None) -> dict:
    """Shares of the held-out gap. Residual and model images are (lines, pixels), residuals line-levelled;
    ``measured`` is the measured (trace, retrace) pair; ``held`` (bool, lines) selects the held-out
    lines; ``with_trace=False`` scores the retrace only. ``error`` (None: no ``z_loop`` entry):
    ``{"channel": name, "trace": image, "retrace": image}``, the Z loop's error signal."""
    res = [retrace_res[held]] if not with_trace else [trace_res[held], retrace_res[held]]
    mod = [retrace_model[held]] if not with_trace else [trace_model[held], retrace_model[held]]
    r = np.stack(res)  # (directions, lines, pixels)
    r2 = r**2
    total = float(r2.sum()) or 1.0
    where = {}
    if with_trace:
        d = np.zeros(r.shape, dtype=bool)
        d[0] = True
        where["direction"] = {"trace": _share(r2, d, total), "retrace": _share(r2, ~d, total)}
    grad = np.gradient(np.stack(mod), axis=2)
    grad = grad - grad.mean(axis=2, keepdims=True)
    shift = np.sum(r * grad, axis=2, keepdims=True) / np.maximum(np.sum(grad**2, axis=2, keepdims=True), 1e-300)
    slow = float(np.sum((shift * grad) ** 2))
    where["axis"] = {"slow": {"share": round(min(slow / total, 1.0), 4)},
                     "fast": {"share": round(max(1.0 - slow / total, 0.0), 4)}}
    slope = np.abs(np.gradient(np.stack([m[held] for m in (measured if with_trace else measured[1:])]), axis=2))
    edges = slope >= np.quantile(slope, 0.8)
    where["features"] = {"edges": _share(r2, edges, total), "flats": _share(r2, ~edges, total)}
    nx = r.shape[2]
    col = np.broadcast_to(np.arange(nx), r.shape)
    where["position"] = {"left": _share(r2, col < nx / 3, total),
                         "centre": _share(r2, (col >= nx / 3) & (col < 2 * nx / 3), total),
                         "right": _share(r2, col >= 2 * nx / 3, total)}
    nl = r.shape[1]
    line = np.broadcast_to(np.arange(nl)[:, None], r.shape[1:])
    early = np.broadcast_to(line < nl / 2, r.shape)
    where["time"] = {"early": _share(r2, early, total), "late": _share(r2, ~early, total)}
    energy = r2.sum(axis=2)  # (directions, lines)
    worst = energy >= np.sort(energy.ravel())[-max(1, int(round(WORST_LINES * energy.size)))]
    where["lines"] = {"worst": _share(r2, np.broadcast_to(worst[:, :, None], r.shape), total)}
    if error is not None:
        where["z_loop"] = _z_loop(error, r2, held, with_trace, total)
    return where


def _z_loop(error: dict, r2, held, with_trace: bool, total: float) -> dict:
    """The ``z_loop`` entry of :func:`localise_image`: each scored direction on its own error signal."""
    own = (error["trace"], error["retrace"]) if with_trace else (error["retrace"],)
    masks = [out_of_regulation(e) for e in own]
    out = {"channel": error["channel"], "directions": "trace and retrace" if with_trace else "retrace"}
    if any(m is None for m in masks):
        return {**out, "constant": True}
    mask = np.stack([m[held] for m in masks])
    return {**out, "threshold_sigma": REGULATION_SIGMA, **_share(r2, mask, total)}
