"""Image-data diagnosis: calibrate the baseline, localise the held-out gap, attribute it, report.

Protocol of :func:`diagnose_images` (the image twin of :func:`~afmsim.diagnosis.diagnose_loops`):

1. lines are split into blocks of ``max(2, lines // 16)``; of every five blocks the 2nd and 4th are
   held out (40 %), the others train; line 0 follows the approach from rest (another hysteresis
   branch) and is neither. No fit sees a held-out line; with the ``scenario`` reference the model
   predicts held-out lines entirely, with the ``trace`` reference it predicts their retrace from
   their own trace (the input, as the voltage is for loops);
2. baseline = rate-independent hysteresis per scan direction + slow-axis scale/curvature, the
   scenario's tip and Z loop (ideal without a scenario), plus every effect the scenario already
   switches on (fitted); heights are compared line-levelled;
3. the held-out residual is localised (:func:`~afmsim.diagnosis.images.localise.localise_image`),
   where the record has the Z loop's error signal also on the pixels where the loop was off its
   setpoint (a localisation only: it does not single out the Z loop);
4. greedy attribution by the engine shared with loops (:mod:`~afmsim.diagnosis.engine`), with the same test (:func:`~afmsim.diagnosis.engine.significance`:
   ΔBIC on the correlation-discounted held-out sample count with the candidate's extra parameters,
   ≥ 70 % of 10 held-out blocks improved, ≥ 3 % RMS drop and ≥ 15 % of the gap above the noise
   floor, σ from second differences of the baseline's training residual). Images are almost
   noise-free, so that test alone lets a flexible candidate pass on the model's own small mismatch
   (Z-loop details, sampling of sharp edges); an effect must in addition shrink the current held-out
   RMS gap by ≥ 20 % and remove ≥ 0.5 % of the baseline's held-out mean square (practical
   significance; both thresholds were set on the development seeds, not on the reported run).
   Effects whose signature the current model already has (:func:`~afmsim.diagnosis.images.fit.redundancy`
   < 0.05) are not fitted but reported ``indistinguishable_from``; ties within 2 BIC units go to the
   first name in canonical order (``ambiguous_with`` lists the others). Every remaining candidate is
   tried again in each round: a large effect can mask a smaller one until it is modelled;
5. status, implausible parameters and the unexplained remainder as the engine defines them
   (:func:`~afmsim.diagnosis.engine.conclude`).

Identifiability. With the ``trace`` reference (no known sample) the trace is the reference, so
``drift``, ``cross_coupling`` and ``tip``, which move or reshape trace and retrace alike, cannot
be seen; they are listed under ``not_identifiable``. With the ``scenario`` reference they can, but
on a sample that does not vary along y (a line grating along y) the slow-axis terms are
undetermined and drift and cross-coupling are the same x-skew; a sample rotated in the scan plane
also reads as that skew.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.polynomial import legendre

from afmsim.reproducible import single_blas_thread

from ..engine import Front, Rules, attribute, conclude, effect_lines, flattest_noise, noise_floor, ratio_text, rms, verdict_text
from ..scenario_effects import as_scenario, modelled_effects
from .fit import ImageDesign, ImageFit, fit_image, redundancy
from .localise import localise_image
from .model import Layout, ZLoop
from .record import ImageRecord, budget_text, load_images, within_budget
from .reference import scenario_reference

__all__ = ["diagnose_images", "diagnose_image_record", "build_design", "split_lines", "effect_params", "sensor_noise",
           "line_offsets",
           "IMAGE_CANDIDATES", "ImageFront"]

IMAGE_CANDIDATES = ("creep", "drift", "dynamics", "cross_coupling", "tip", "z_feedback", "z_bow", "asymmetry")
#: a candidate whose signature the model already has to 95 % is not fitted; an effect must remove
#: ≥ 0.5 % of the baseline's held-out mean square and ≥ 20 % of the current held-out RMS gap; ΔBIC
#: within 2 of the best is equal evidence (the earlier canonical name is taken)
RULES = Rules(max_effects=3, min_step=0.2, min_baseline_share=0.005, tie_bic=2.0, redundant=0.05)
NOT_IDENTIFIABLE_WITHOUT_SAMPLE = {
    "drift": "moves trace and retrace alike: needs a known sample (--scenario)",
    "cross_coupling": "moves trace and retrace alike: needs a known sample (--scenario)",
    "tip": "broadens trace and retrace alike: needs a known sample (--scenario)",
}


def split_lines(lines: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, held) line masks: blocks of max(2, lines // 16), blocks 1 and 3 of every 5 held out, line 0 in neither."""
    idx = np.arange(lines)
    block = (idx - 1) // max(2, lines // 16)
    held = (idx >= 1) & np.isin(block % 5, (1, 3))
    train = (idx >= 1) & ~held
    if held.sum() < 4 or train.sum() < 6:
        raise ValueError(f"too few lines ({lines}) to keep held-out lines apart from training lines")
    return train, held


def build_design(record: ImageRecord, scenario=None, *, reference: str = "auto", baseline: str = "asymmetric"):
    """The :class:`ImageDesign` of a record: reference surface, known Z loop and tip, line split.

    ``reference``: ``"scenario"`` (the scenario's sample and tip; needs ``scenario``), ``"trace"``
    (the measured trace), ``"auto"`` (scenario when one is given).
    """
    if baseline not in ("asymmetric", "symmetric"):
        raise ValueError(f"baseline must be 'asymmetric' or 'symmetric', got {baseline!r}")
    if reference == "auto":
        reference = "scenario" if scenario is not None else "trace"
    if reference not in ("scenario", "trace"):
        raise ValueError(f"reference must be 'scenario', 'trace' or 'auto', got {reference!r}")
    if reference == "scenario" and scenario is None:
        raise ValueError("the scenario reference needs --scenario (the imaged sample and tip)")
    offset = record.scan_offset_m
    if offset is None:
        offset = tuple(v * 1e-6 for v in scenario.scan.offset_um) if scenario is not None else (0.0, 0.0)
    approach = scenario.numerics.approach_s if scenario is not None else 1.0
    layout = Layout(record.shape, record.scan_size_m, offset, record.line_rate_hz, approach)
    train, held = split_lines(record.shape[0])
    z_loop, tip_r, surface, sample = None, None, None, None
    if scenario is not None:
        zf = scenario.z_feedback
        z_loop = ZLoop(zf.ki_per_s, zf.kp, zf.setpoint_nm * 1e-9)
        tip_r = scenario.tip.apex_radius_nm * 1e-9
        if reference == "scenario":
            surface, sample, _tip = scenario_reference(scenario, layout.geometry)
    design = ImageDesign(record, layout, surface, z_loop=z_loop, tip_radius_m=tip_r, baseline=baseline,
                         train=train, held=held, sample=sample)
    return design


def effect_params(design: ImageDesign, fit: ImageFit, effect: str) -> dict:
    """The fitted parameters of ``effect`` in SI units (names carry the unit)."""
    if effect == "creep":
        return {"gamma_per_decade": fit.coefficient("creep", "gamma")}
    if effect == "drift":
        return {"rate_m_per_s": fit.coefficient("drift", "rate")}
    if effect == "cross_coupling":
        return {"coefficient": fit.coefficient("cross_coupling", "coefficient")}
    if effect == "asymmetry":
        return {"terms_m": {c.name: float(v) for c, v in zip(fit.columns, fit.theta) if c.group == "asymmetry"}}
    if effect == "z_bow":
        return bow_params(design, fit)
    if effect == "dynamics":
        f0, zeta = fit.hyper["dynamics"]
        return {"resonance_hz": float(f0), "damping_ratio": float(zeta)}
    if effect == "z_feedback":
        kp = design.z_loop.kp if design.z_loop else 0.1
        ki = float(fit.hyper["z_feedback"])
        return {"ki_per_s": ki, "time_constant_s": (1.0 + kp) / ki}
    if effect == "tip":
        extra = float(fit.hyper["tip"])
        known = design.tip_radius_m or 0.0
        return {"apex_radius_m": known + extra, "extra_paraboloid_radius_m": extra, "known_apex_radius_m": known}
    return {}


def bow_params(design: ImageDesign, fit: ImageFit) -> dict:
    """``z_bow`` in SI: peak-to-valley (m) of the retrace − trace height background along the line (and,
    scenario reference, of the background both directions share), and that difference as a share of
    the median Z range a measured trace line sweeps (the Z-piezo loop's width is a share of it)."""
    u = np.linspace(-1.0, 1.0, 201)
    coef = {c.name: float(v) for c, v in zip(fit.columns, fit.theta) if c.group == "z_bow"}
    order = max(int(n.rsplit("P", 1)[1]) for n in coef)

    def profile(prefix: str, factor: float) -> np.ndarray:
        return factor * legendre.legval(u, [0.0] + [coef.get(f"{prefix}_P{k}", 0.0) for k in range(1, order + 1)])

    diff = profile("retrace", 1.0) if design.kind == "trace" else profile("width", 2.0)
    lines = design.record.trace[design.train | design.held]
    out = {"difference_ptp_m": float(np.ptp(diff)),
           "share_of_line_z_range": float(np.ptp(diff) / max(float(np.median(np.ptp(lines, axis=1))), 1e-300))}
    if design.kind != "trace":
        out["common_ptp_m"] = float(np.ptp(profile("mean", 1.0)))
    return out


def sensor_noise(record: ImageRecord, lines: np.ndarray) -> float:
    """White height noise (m) of the instrument, from the measured images themselves
    (:func:`~afmsim.diagnosis.engine.flattest_noise` over the ``lines`` of both directions).
    Independent of any model; biased low for pure white noise, so gaps against it read
    conservatively high."""
    return flattest_noise((record.trace[lines], record.retrace[lines]))


def line_offsets(record: ImageRecord, lines: np.ndarray) -> dict:
    """Line-to-line height offsets between the scan directions (m), from the measured images alone.

    The scores compare lines levelled (one free offset per line and direction): an offset is not
    predictable for a held-out line and carries no XY information. Reported here instead: the
    median retrace − trace offset of a line's means (Z creep or drift between the directions) and its
    line-to-line jitter, the robust σ of its second differences over lines / √6 (a slow trend along
    y drops out; topography cancels between the directions) — the datasheet's 0.5–5 nm."""
    off = record.retrace[lines].mean(axis=1) - record.trace[lines].mean(axis=1)
    jitter = noise_floor(off) if off.size > 2 else float("nan")
    return {"retrace_minus_trace_m": float(np.median(off)), "jitter_m": jitter}


def _held_rows(design: ImageDesign, fit: ImageFit, lines) -> np.ndarray:
    rec = design.record
    return design.rows(lines, rec.trace - fit.trace, rec.retrace - fit.retrace)


class ImageFront(Front):
    """The image pair's side of the engine: the raster forward model fitted by :func:`fit_image`."""

    def __init__(self, design: ImageDesign):
        self.design = design
        rec = design.record
        self.error = None if rec.error_trace is None else \
            {"channel": rec.error_channel, "trace": rec.error_trace, "retrace": rec.error_retrace}

    def fit(self, effects: tuple, start=None) -> ImageFit:
        return fit_image(self.design, effects, start=start)

    def refresh(self, effects: tuple, fitted: ImageFit) -> ImageFit:
        # continue the accepted model's fit, so a candidate is not credited with its convergence
        return fit_image(self.design, effects, start=fitted)

    def heldout_residual(self, fitted: ImageFit) -> np.ndarray:
        return _held_rows(self.design, fitted, self.design.held)

    def train_residual(self, fitted: ImageFit) -> np.ndarray:
        return _held_rows(self.design, fitted, self.design.train)

    def n_params(self, fitted: ImageFit) -> int:
        return fitted.n_params

    def effect_params(self, fitted: ImageFit, effect: str) -> dict:
        return effect_params(self.design, fitted, effect)

    def localise(self, fitted: ImageFit) -> dict:
        d = self.design
        return localise_image(*_images_residual(d, fitted), fitted.trace, fitted.retrace,
                              (d.record.trace, d.record.retrace), d.held,
                              with_trace=d.kind == "scenario", error=self.error)

    def redundancy(self, fitted: ImageFit, effect: str) -> float:
        return redundancy(self.design, fitted, effect)


def _candidates(design: ImageDesign, modelled) -> tuple[list[str], dict]:
    out, skipped = [], {}
    for c in IMAGE_CANDIDATES:
        if c in modelled:
            continue
        if c == "asymmetry" and design.baseline != "symmetric":
            continue
        if design.kind == "trace" and c in NOT_IDENTIFIABLE_WITHOUT_SAMPLE:
            skipped[c] = NOT_IDENTIFIABLE_WITHOUT_SAMPLE[c]
            continue
        out.append(c)
    return out, skipped


@single_blas_thread
def diagnose_image_record(record: ImageRecord, scenario=None, *, reference: str = "auto", baseline: str = "asymmetric",
                          candidates=None, figure_path=None) -> tuple[dict, str, dict]:
    """Diagnosis of a validated image pair; returns ``(report, summary, internals)``.

    ``candidates`` restricts the effects tried (default: every identifiable one not modelled).
    """
    record, cut = within_budget(record)
    design = build_design(record, scenario, reference=reference, baseline=baseline)
    modelled = modelled_effects(scenario)
    front = ImageFront(design)
    base = front.fit(modelled)
    sigma = noise_floor(_held_rows(design, base, design.train))
    sensor = sensor_noise(record, design.train)
    avail, skipped = _candidates(design, modelled)
    if candidates is not None:
        avail = [c for c in candidates if c in avail]
    att = attribute(front, avail, sigma, modelled=modelled, rules=RULES, baseline=base)
    outcome = conclude(front, att, sigma, avail, rules=RULES)
    block = max(2, record.shape[0] // 16)
    report = {
        "images": {"source": record.source, "lines": record.shape[0], "pixels": record.shape[1],
                   "scan_size_m": list(record.scan_size_m), "line_rate_hz": record.line_rate_hz,
                   "filled_pixels": record.filled_pixels, "unscanned_lines": record.unscanned_lines,
                   "reference": design.kind,
                   "train_lines": int(design.train.sum()), "heldout_lines": int(design.held.sum()),
                   "split": f"blocks of {block} lines from line 1, the 2nd and 4th of every 5 held out; line 0 "
                            "(after the approach) in neither", **({"cut": cut} if cut else {})},
        "status": outcome["status"],
        "baseline": {"model": f"{design.baseline} rate-independent hysteresis per scan direction (Legendre), "
                              f"slow-axis scale, {design.kind} reference, "
                              f"{'scenario Z loop' if design.z_loop else 'ideal Z loop'}",
                     "modelled": list(modelled), "rms_gap": rms(front.heldout_residual(base)), "unit": "m",
                     "gap_to_noise": outcome["baseline_gap"]["gap_to_noise"],
                     "train_rms": rms(_held_rows(design, base, design.train)), "noise_floor": sigma,
                     "sensor_noise": sensor, "gap_to_sensor_noise": _ratio(rms(front.heldout_residual(base)), sensor),
                     "height_range": float(np.ptp(record.trace)), "params": _baseline_params(design, base),
                     "line_offsets": line_offsets(record, design.train | design.held)},
        "where": front.localise(base),
        "effects": [att.evaluations[c] for c in avail if c in att.evaluations],
        "not_identifiable": skipped,
        "verdict": outcome["verdict"],
        "findings": outcome["findings"],
        "implausible": outcome["implausible"],
        "final": outcome["final"],
        "unexplained": outcome["unexplained"],
    }
    if record.error_channel is not None:
        report["images"]["error_channel"] = record.error_channel
    report["final"]["gap_to_sensor_noise"] = _ratio(report["final"]["rms_gap"], sensor)
    unscanned = (f"Frame stopped early: the last {record.unscanned_lines} of "
                 f"{record.shape[0] + record.unscanned_lines} lines hold no scan (NaN or one fill value); diagnosed "
                 f"the {record.shape[0]} scanned, the scan height cut to {record.scan_size_m[1] * 1e6:.4g} µm.\n"
                 if record.unscanned_lines else "")
    summary = unscanned + (budget_text(cut) + "\n" if cut else "") + image_summary(report)
    if figure_path is not None:
        plot_image_diagnosis(design, base, att.final, figure_path,
                             title=f"{report['status']}: " + (", ".join(outcome["verdict"]) or "no effect named"))
        report["figure"] = str(figure_path)
    return report, summary, {"design": design, "baseline": base, "final": att.final}


def _ratio(gap: float, sigma: float):
    return round(gap / sigma, 3) if sigma > 0 else None


def _images_residual(design: ImageDesign, fit: ImageFit):
    rec = design.record
    rt = rec.trace - fit.trace
    rr = rec.retrace - fit.retrace
    return rt - rt.mean(axis=1, keepdims=True), rr - rr.mean(axis=1, keepdims=True)


def _baseline_params(design: ImageDesign, fit: ImageFit) -> dict:
    lay = design.layout
    out = {"height_gain": fit.gain}
    if design.kind == "scenario":
        out["stage_scale_x"] = float(np.polyfit(lay.u, fit.x, 1)[0])
        out["stage_scale_y"] = float(np.polyfit(lay.v, fit.y, 1)[0])
    xt, xr = lay.images(fit.x)
    out["trace_retrace_shift_m"] = float(np.mean(xr - xt)) if design.kind == "scenario" else \
        float(np.mean(xr - lay.images(lay.u)[1]))
    return out


def where_text(w: dict) -> str:
    """One line on where an image pair's held-out gap lies."""
    parts = [f"slow/fast axis {w['axis']['slow']['share']:.0%}/{w['axis']['fast']['share']:.0%}",
             f"edges {w['features']['edges']['share']:.0%} of gap on {w['features']['edges']['sample_fraction']:.0%} of pixels",
             "left/centre/right {:.0%}/{:.0%}/{:.0%}".format(*(w["position"][k]["share"] for k in ("left", "centre", "right"))),
             f"early/late lines {w['time']['early']['share']:.0%}/{w['time']['late']['share']:.0%}"]
    if "lines" in w:
        parts.append(f"worst {w['lines']['worst']['sample_fraction']:.0%} of lines {w['lines']['worst']['share']:.0%}")
    if "direction" in w:
        parts.insert(0, f"trace/retrace {w['direction']['trace']['share']:.0%}/{w['direction']['retrace']['share']:.0%}")
    if "z_loop" in w and not w["z_loop"].get("constant"):
        z = w["z_loop"]
        parts.append(f"error signal off its setpoint ({z['directions']}'s own {z['channel']} > {z['threshold_sigma']:g}σ) "
                     f"{z['share']:.0%} of gap on {z['sample_fraction']:.0%} of pixels")
    return "; ".join(parts) + "."


def image_summary(rep: dict) -> str:
    """Terminal summary of an image diagnosis report."""
    b = rep["baseline"]
    lines = [f"Baseline ({b['model']}): held-out RMS gap {b['rms_gap'] * 1e9:.2f} nm "
             f"({100 * b['rms_gap'] / (b['height_range'] or 1):.2f} % of the height range; noise floor "
             f"{b['noise_floor'] * 1e9:.2f} nm, gap {ratio_text(b['gap_to_noise'])} the noise)."]
    if b["sensor_noise"] > 0 and b["noise_floor"] > 2.0 * b["sensor_noise"]:
        lines.append(f"Note: the noise floor (white part of the residual) is {b['noise_floor'] / b['sensor_noise']:.1f}× "
                     f"the sensor noise seen on the flattest parts of the images ({b['sensor_noise'] * 1e9:.2f} nm): it "
                     f"holds pixel-scale model error (sub-pixel structure the reference cannot resample), so the "
                     f"status is relative to that floor; against the sensor noise the final gap is "
                     f"{ratio_text(rep['final']['gap_to_sensor_noise'])}.")
    lines.append("Where: " + where_text(rep["where"]))
    lines += effect_lines(rep["effects"])
    for name, why in rep["not_identifiable"].items():
        lines.append(f"  {name:<15} not identifiable: {why}")
    lines.append(verdict_text(rep, where_text))
    return "\n".join(lines)


def plot_image_diagnosis(design: ImageDesign, before: ImageFit, after: ImageFit, path, *, title="") -> Path:
    """Residual images (nm, line-levelled) of the baseline and of the verdict, trace and retrace, held-out lines marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    res = [_images_residual(design, f) for f in (before, after)]
    lim = max(float(np.abs(r[design.train | design.held]).max()) for pair in res for r in pair) * 1e9 or 1.0
    w, h = design.record.scan_size_m
    extent = [0, w * 1e6, 0, h * 1e6]
    fig, axes = plt.subplots(2, 3, figsize=(13, 7.5), constrained_layout=True,
                             gridspec_kw={"width_ratios": [1, 1, 0.8]})
    for row, (label, pair) in enumerate(zip(("baseline", "with verdict"), res)):
        for col, (name, img) in enumerate(zip(("trace", "retrace"), pair)):
            ax = axes[row, col]
            shown = ax.imshow(img * 1e9, origin="lower", extent=extent, cmap="RdBu_r", vmin=-lim, vmax=lim,
                              interpolation="nearest")
            ax.set(title=f"{label}: {name} residual", xlabel="x (µm)", ylabel="y (µm)")
    fig.colorbar(shown, ax=axes[:, :2], label="data − model, line-levelled (nm)", shrink=0.8)
    lines = np.arange(design.record.shape[0])
    scored = design.train | design.held  # line 0, after the approach, is neither
    for row, pair in enumerate(res):
        ax = axes[row, 2]
        for name, img, colour in (("trace", pair[0], "tab:red"), ("retrace", pair[1], "tab:blue")):
            ax.plot(np.where(scored, np.sqrt(np.mean(img**2, axis=1)), np.nan) * 1e9, lines, color=colour, lw=1,
                    label=name)
        for k in np.nonzero(design.held)[0]:
            ax.axhspan(k - 0.5, k + 0.5, color="0.9", lw=0)
        ax.set(xlabel="RMS per line (nm)", ylabel="line", title="grey: held-out lines", xlim=(0, None))
        ax.legend(fontsize=8)
    fig.suptitle(f"afmsim image diagnosis — verdict: {title}")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def diagnose_images(source, *, scenario=None, reference: str = "auto", baseline: str = "asymmetric",
                    channel: str | None = None, figure_path=None, rng_seed: int = 0,
                    reverse_lines: bool = False) -> tuple[dict, str]:
    """Diagnose a measured trace/retrace pair: a path of any file :func:`afmsim.readers.read_afm_file` reads, a
    dict of arrays, or an :class:`~afmsim.diagnosis.images.record.ImageRecord` already loaded.

    ``scenario`` (a :class:`~afmsim.scenario.Scenario` or a YAML path) gives the imaged sample, the
    tip, the Z loop and the effects already modelled; without it the trace is the reference.
    Returns ``(report, summary)``; ``report`` is JSON-serialisable (``diagnosis.json``).
    ``rng_seed`` is recorded for provenance; the diagnosis is deterministic. ``reverse_lines``: the
    file stores its lines last-scanned first (:func:`~afmsim.diagnosis.images.record.load_images`).
    """
    scenario = as_scenario(scenario)
    rate = scenario.scan.line_rate_hz if scenario is not None else None
    record = load_images(source, channel=channel, line_rate_hz=rate, reverse_lines=reverse_lines)
    report, summary, _ = diagnose_image_record(record, scenario, reference=reference, baseline=baseline,
                                               figure_path=figure_path)
    report["rng_seed"] = int(rng_seed)
    return report, summary
