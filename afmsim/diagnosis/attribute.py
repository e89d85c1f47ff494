"""Calibrate the baseline, attribute the held-out gap to candidate effects, report (``diagnosis.json``).

Protocol of :func:`diagnose_loops`:

1. the record is validated/decimated (:func:`~afmsim.diagnosis.loops.load_record`); the first
   ``train_fraction`` (60 %) of the time is the training part, the rest is held out and seen by
   no fit;
   held-out samples whose voltage leaves the training range (by > 1 %) are not scored (no
   rate-independent model can know untrained relays); the scored fraction is reported;
2. baseline = rate-independent hysteresis (relay Preisach grid, or play operators with
   ``baseline="symmetric"``) + offset + linear term, fitted on the training part;
3. the held-out residual is localised (:func:`~afmsim.diagnosis.localise.localise`);
4. greedy attribution: each remaining candidate is added to the current model, fitted on the
   training part, and scored on the held-out part. The best one is accepted only if it is
   *significant*: (a) its held-out RSS drops with ΔBIC < −6, BIC computed with an effective
   sample count ``n_eff = n / L`` where L is the decorrelation length of the current held-out
   residual (so autocorrelated model error does not count as independent evidence), with the
   candidate's extra parameters as penalty; (b) at least 70 % of 10 contiguous held-out blocks
   improve (a block test, robust to one lucky segment); (c) the held-out RMS drops by ≥ 3 %, and
   by ≥ 15 % of the part of the current gap above the sensor-noise floor (σ from second
   differences). Among the significant candidates the one with the most negative ΔBIC is added;
   repeated while one is significant (at most 3 effects). ``heldout_shrink`` of an effect is the
   shrink of the model it was last tried in (``added_to`` lists what that model already had);
   ``heldout_shrink_alone`` is baseline + that effect only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from afmsim.reproducible import single_blas_thread

from .localise import localise
from .loops import LoopRecord, load_record
from .model import Design, ModelSpec, fit_model

__all__ = ["diagnose_loops", "diagnose_record", "noise_floor", "significance"]

TRAIN_FRACTION = 0.6
MAX_EFFECTS = 3


def noise_floor(x) -> float:
    """Robust white-noise σ of x from its second differences (σ_Δ² = √6·σ)."""
    d2 = np.diff(x, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def _decorrelation_length(r) -> float:
    r = r - r.mean()
    n = r.size
    f = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    if acf[0] <= 0:
        return 1.0
    acf /= acf[0]
    below = np.nonzero(acf < np.exp(-1))[0]
    return float(max(1, below[0] if below.size else n))


def significance(r0, r1, sigma, k_extra, *, n_blocks=10) -> dict:
    """Evidence that the candidate residual ``r1`` improves on ``r0`` (both held-out)."""
    n = r0.size
    rss0, rss1 = float(np.sum(r0**2)), float(np.sum(r1**2))
    step = 1.0 - np.sqrt(rss1 / rss0) if rss0 > 0 else 0.0
    n_eff = max(n / _decorrelation_length(r0), 5.0)
    dbic = n_eff * np.log(max(rss1, 1e-300) / rss0) + k_extra * np.log(n_eff)
    blocks = np.array_split(r0**2 - r1**2, n_blocks)
    frac_pos = float(np.mean([b.mean() > 0 for b in blocks]))
    excess = rss0 / n - sigma**2
    gain = (rss0 - rss1) / n
    ok = bool(dbic < -6 and frac_pos >= 0.7 and step >= 0.03 and excess > 0 and gain >= 0.15 * excess)
    return {"step_shrink": float(step), "delta_bic": float(dbic), "n_eff": float(n_eff),
            "blocks_improved": frac_pos, "gain_over_excess": float(gain / excess) if excess > 0 else 0.0,
            "significant": ok}


def _available(rec: LoopRecord, baseline: str) -> list[str]:
    c = ["creep", "drift", "dynamics"]
    if rec.y is not None:
        c.append("cross_coupling")
    if baseline == "symmetric":
        c.append("asymmetry")
    return c


def _rms(a) -> float:
    return float(np.sqrt(np.mean(a**2)))


@single_blas_thread
def diagnose_record(rec: LoopRecord, *, baseline: str = "preisach", candidates=None, figure_path=None,
                    train_fraction: float = TRAIN_FRACTION, modelled=()) -> tuple[dict, str, dict]:
    """Diagnosis of a validated record; returns ``(report, summary, internals)``.

    ``modelled``: effects the model already has (a scenario's stage switches); they are fitted with
    the baseline and are not candidates.
    """
    if baseline not in ("preisach", "symmetric"):
        raise ValueError(f"baseline must be 'preisach' or 'symmetric', got {baseline!r}")
    n = rec.n
    train = np.arange(n) < int(round(train_fraction * n))
    d = Design(rec.t, rec.v, rec.x, rec.y, train)
    held = ~train & d.in_range  # held-out samples beyond the trained voltage range are not scored
    if held.sum() < 50:
        raise ValueError(f"only {int(held.sum())} held-out samples lie inside the training voltage range; "
                         "the record's excitation must repeat its range after the first 60 %")
    sigma = noise_floor(rec.x)
    modelled = tuple(m for m in modelled if m != "cross_coupling" or rec.y is not None)
    base = fit_model(d, ModelSpec(kind=baseline, effects=modelled))
    r_base = rec.x - base.prediction
    rms_base = _rms(r_base[held])
    where = localise(rec.t, rec.v, rec.x, r_base, held)
    avail = [c for c in (list(candidates) if candidates is not None else _available(rec, baseline)) if c not in modelled]
    current, cur_fit, cur_r = modelled, base, r_base
    evaluations: dict[str, dict] = {}
    first_round = True
    for _ in range(MAX_EFFECTS):
        remaining = [c for c in avail if c not in current]
        if not remaining:
            break
        trial = {}
        for c in remaining:
            fm = fit_model(d, ModelSpec(kind=baseline, effects=current + (c,)))
            r1 = rec.x - fm.prediction
            sig = significance(cur_r[held], r1[held], sigma, max(fm.n_params - cur_fit.n_params, 1))
            trial[c] = (fm, r1, sig)
            evaluations[c] = {"name": c, "params": fm.params.get(c, {}),
                              "heldout_shrink": round(1.0 - _rms(r1[held]) / rms_base, 4) if rms_base > 0 else 0.0,
                              "significant": False, "test": {k: (round(v, 4) if isinstance(v, float) else v)
                                                             for k, v in sig.items()}, "added_to": list(current)}
        if first_round:
            for c in remaining:
                evaluations[c]["heldout_shrink_alone"] = evaluations[c]["heldout_shrink"]
            first_round = False
        sig_ok = [c for c in remaining if trial[c][2]["significant"]]
        if not sig_ok:
            break
        best = min(sig_ok, key=lambda c: trial[c][2]["delta_bic"])  # strongest evidence first
        fm, r1, sig = trial[best]
        evaluations[best]["significant"] = True
        current, cur_fit, cur_r = current + (best,), fm, r1
    # final parameters of accepted effects come from the final joint fit
    verdict = [c for c in current if c not in modelled]
    for c in verdict:
        evaluations[c]["params"] = cur_fit.params.get(c, {})
    effects = [evaluations[c] for c in avail if c in evaluations]
    report = {
        "record": {"source": rec.source, "samples": n, "sample_interval_s": rec.dt, "decimation": rec.decimation,
                   "duration_s": float(rec.t[-1] - rec.t[0]), "train_fraction": train_fraction,
                   "heldout_from_s": float(rec.t[~train][0]),
                   "heldout_scored_fraction": round(float(held.sum() / (~train).sum()), 4), "has_cross_axis": rec.y is not None},
        "baseline": {"model": "relay Preisach grid (asymmetric)" if baseline == "preisach" else
                     "play operators (symmetric PI)", "rms_gap": rms_base, "unit": "m",
                     "train_rms": _rms(r_base[train]), "noise_floor": sigma,
                     "travel": float(np.ptp(rec.x)), "modelled": list(modelled)},
        "where": where,
        "effects": effects,
        "verdict": verdict,
        "final": {"rms_gap": _rms(cur_r[held]), "heldout_shrink": round(1.0 - _rms(cur_r[held]) / rms_base, 4)
                  if rms_base > 0 else 0.0},
    }
    summary = _summary(report)
    if figure_path is not None:
        plot_diagnosis(rec, r_base, cur_r, held, figure_path, title=", ".join(verdict) or "nothing missing")
        report["figure"] = str(figure_path)
    return report, summary, {"design": d, "baseline": base, "final": cur_fit, "held": held}


def _summary(rep: dict) -> str:
    b = rep["baseline"]
    lines = [f"Baseline ({b['model']}): held-out RMS gap {b['rms_gap'] * 1e9:.1f} nm "
             f"({100 * b['rms_gap'] / (b['travel'] or 1):.2f} % of travel; noise floor {b['noise_floor'] * 1e9:.1f} nm)."]
    w = rep["where"]
    lines.append("Where: time early/late {:.0%}/{:.0%}; holds {:.0%} of gap on {:.0%} of samples; "
                 "rising/falling {:.0%}/{:.0%}; below-excitation frequencies {:.0%}.".format(
                     w["time"]["early"]["share"], w["time"]["late"]["share"], w["motion"]["hold"]["share"],
                     w["motion"]["hold"]["sample_fraction"], w["branch"]["rising"]["share"],
                     w["branch"]["falling"]["share"], w["frequency"]["below_excitation"]))
    for e in rep["effects"]:
        lines.append(f"  {e['name']:<15} shrink {e['heldout_shrink']:+.1%}  ΔBIC {e['test']['delta_bic']:+.1f}  "
                     f"{'SIGNIFICANT' if e['significant'] else 'not significant'}  {_fmt_params(e['params'])}")
    v = rep["verdict"]
    lines.append("Verdict: the model is missing " + ", then ".join(v) + f" (held-out gap shrinks "
                 f"{rep['final']['heldout_shrink']:.0%})." if v else "Verdict: nothing significant is missing.")
    return "\n".join(lines)


def _fmt_params(p: dict) -> str:
    keep = {k: v for k, v in p.items() if isinstance(v, (int, float))}
    return ", ".join(f"{k}={v:.3g}" for k, v in keep.items())


def plot_diagnosis(rec: LoopRecord, r_before, r_after, held, path, *, title="") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    t0 = rec.t[held][0]
    ax[0].plot(rec.t, r_before * 1e9, lw=0.6, color="tab:red", label="baseline")
    ax[0].plot(rec.t, r_after * 1e9, lw=0.6, color="tab:blue", label="with verdict")
    ax[0].axvline(t0, color="k", ls="--", lw=0.8)
    ax[0].text(t0, ax[0].get_ylim()[1], " held-out", va="top", fontsize=8)
    ax[0].set(xlabel="t (s)", ylabel="residual x − model (nm)", title="residual vs time")
    ax[0].legend(fontsize=8)
    ax[1].plot(rec.x[held] * 1e6, r_before[held] * 1e9, ".", ms=1.5, color="tab:red", label="baseline")
    ax[1].plot(rec.x[held] * 1e6, r_after[held] * 1e9, ".", ms=1.5, color="tab:blue", label="with verdict")
    ax[1].set(xlabel="x (µm)", ylabel="held-out residual (nm)", title="residual vs position (held-out)")
    ax[1].legend(fontsize=8, markerscale=6)
    fig.suptitle(f"afmsim diagnosis — verdict: {title}")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def diagnose_loops(path_or_arrays, *, rng_seed: int = 0, figure_path=None, baseline: str = "preisach",
                   scenario=None) -> tuple[dict, str]:
    """Diagnose a measured record (CSV path, dict of columns or ``(t, v, x[, y])``).

    ``scenario`` (a Scenario or YAML path): effects its stage switches on are already modelled.
    Returns ``(report, summary)``; ``report`` is JSON-serialisable (``diagnosis.json``).
    ``rng_seed`` is recorded for provenance; the diagnosis itself is deterministic.
    """
    from .scenario_effects import as_scenario, modelled_effects

    modelled = modelled_effects(as_scenario(scenario))
    rec = load_record(path_or_arrays)
    report, summary, _ = diagnose_record(rec, baseline=baseline, figure_path=figure_path, modelled=modelled)
    report["rng_seed"] = int(rng_seed)
    return report, summary
