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
  picked up or dragged, a feedback glitch — that no stage or Z-loop term predicts.
"""

from __future__ import annotations

import numpy as np

__all__ = ["localise_image"]

WORST_LINES = 0.05  # share of the held-out lines counted as the worst


def _share(r2: np.ndarray, mask: np.ndarray, total: float) -> dict:
    return {"share": round(float(r2[mask].sum()) / total, 4), "sample_fraction": round(float(mask.mean()), 4)}


def localise_image(trace_res, retrace_res, trace_model, retrace_model, measured, held, *, with_trace=True) -> dict:
    """Shares of the held-out gap. Residual and model images are (lines, pixels), residuals line-levelled;
    ``measured`` is the measured (trace, retrace) pair; ``held`` (bool, lines) selects the held-out
    lines; ``with_trace=False`` scores the retrace only."""
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
    return where
