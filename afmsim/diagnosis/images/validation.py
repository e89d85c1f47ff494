"""Proof on withheld data for the image diagnosis: simulated scans with known missing effects.

Each case draws a sample (HS-500MG-like line grating or micro-lens array) and scan settings, scans
it with the simulator (:func:`afmsim.scan.scan_frame`: asymmetric Preisach XY plant driven by the
uncompensated controller, tip-dilated surface, PI Z loop at 50 kHz with a Bouc–Wen Z stage and
deflection noise) with the case's effect(s) switched on in the *simulator's* code — creep bank,
linear thermal drift, amplifier + mechanical resonance, X↔Y coupling (:mod:`afmsim.stage`), a
blunter paraboloid tip (:func:`afmsim.tip.dilate`), a lower Z-loop integral gain — and diagnoses
the images with the case's scenario *without* the effect (stage effects off, the nominal 20 nm
tip, ki = 3000 s⁻¹). The diagnosis' candidates are its own parametric terms
(:mod:`~afmsim.diagnosis.images.model`), not these code paths.

Samples per effect: drift and cross-coupling only on micro-lens arrays — on a grating whose lines
run along y both are the same x-skew (the report then says ``ambiguous_with``), so a grating case
could not be scored; the other effects alternate grating and lenses with the magnitude.

Scores: top-1 accuracy (first verdict entry is a true effect; nulls: empty verdict), also over the
detectable cases only (the oracle shrinks the gap by ≥ 10 %: a 200 nm tip on smooth lenses, for
one, changes next to nothing), exact-set accuracy, false-alarm rate on nulls, parameter recovery
(creep γ, drift rate, coupling c, tip apex radius, resonance f0, ki; relative error, cases where
the effect was found), and the held-out shrink relative to the oracle's: the same scan simulated
without the effects (same noise) and fitted by the baseline leaves what a model with the exact
effect would leave.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from afmsim.compensation import build_controller
from afmsim.experiment import build_sample, scan_geometry
from afmsim.scan import ZFeedback, ZStage, raster_trajectory, scan_frame
from afmsim.scenario import parse_scenario
from afmsim.stage import default_stage
from afmsim.tip import dilate, mlct_tip

from ..engine import STATUSES
from .attribute import build_design, diagnose_image_record
from .fit import fit_image
from .record import load_images

__all__ = ["validate_image_diagnosis", "image_case_plan", "make_image_case", "IMAGE_MAGNITUDES"]

IMAGE_MAGNITUDES = {
    "creep": (0.008, 0.015, 0.03),           # γ per decade
    "drift": (1.5e-9, 4e-9, 10e-9),          # m/s, both axes
    "dynamics": (200.0, 120.0, 70.0),        # resonance f0 (Hz), ζ = 0.05, amplifier 3 kHz
    "cross_coupling": (0.004, 0.01, 0.025),  # X↔Y coupling coefficient
    "tip": (80e-9, 200e-9, 500e-9),          # paraboloid apex radius (m); the model's is 20 nm
    "z_feedback": (1500.0, 600.0, 200.0),    # Z-loop ki (1/s); the model's is 3000
}
IMAGE_PAIRS = (("creep", "z_feedback"), ("drift", "tip"), ("dynamics", "cross_coupling"), ("tip", "z_feedback"),
               ("creep", "dynamics"), ("drift", "z_feedback"))
LENS_ONLY = ("drift", "cross_coupling")
KNOWN_TIP_M, KNOWN_KI = 20e-9, 3000.0
DAMPING = 0.05


def image_case_plan(n_cases: int) -> list[tuple[str, int]]:
    """Case specs ``(kind, k)``: singles ``(effect, magnitude index)``, ``("pair", i)``, ``("null", i)``,
    interleaved so that any prefix mixes them."""
    singles = [(e, k) for k in range(3) for e in IMAGE_MAGNITUDES]
    pairs = [("pair", i) for i in range(len(IMAGE_PAIRS))]
    plan, s, p, z = [], 0, 0, 0
    while len(plan) < n_cases:
        slot = len(plan) % 8
        if slot in (0, 4):
            plan.append(("null", z))
            z += 1
        elif slot == 7 and p < len(pairs):
            plan.append(pairs[p])
            p += 1
        elif s < len(singles):
            plan.append(singles[s])
            s += 1
        elif p < len(pairs):
            plan.append(pairs[p])
            p += 1
        else:
            plan.append(("null", z))
            z += 1
    return plan


def _effects(spec) -> dict:
    kind, k = spec
    if kind == "null":
        return {}
    if kind == "pair":
        a, b = IMAGE_PAIRS[k % len(IMAGE_PAIRS)]
        return {a: IMAGE_MAGNITUDES[a][1], b: IMAGE_MAGNITUDES[b][1]}
    return {kind: IMAGE_MAGNITUDES[kind][k]}


def _scenario(spec, effects, rng: np.random.Generator, pixels: int):
    """The model's scenario (no effects): sample and scan drawn from ``rng``, ``pixels`` × ``pixels``."""
    kind, k = spec
    lens = any(e in LENS_ONLY for e in effects) or (k % 2 == 1)
    if lens:
        d = float(rng.uniform(4.0, 7.0))
        sample = {"kind": "microlens", "diameter_um": d, "sag_um": float(rng.uniform(0.3, 0.8)),
                  "pitch_um": float(d + rng.uniform(1.5, 3.0))}
    else:
        sample = {"kind": "grating", "period_um": float(rng.uniform(3.0, 5.0)), "step_nm": float(rng.uniform(150, 400)),
                  "sidewall_deg": float(rng.uniform(55, 80))}
    size = float(rng.uniform(12.0, 18.0))
    return parse_scenario({
        "name": "image-validation", "sample": sample,
        "tip": {"shape": "paraboloid", "apex_radius_nm": KNOWN_TIP_M * 1e9},
        "stage": {"creep": False, "drift": False, "dynamics": False, "cross_coupling": 0.0},
        "z_feedback": {"ki_per_s": KNOWN_KI, "deflection_noise_nm": float(rng.uniform(0.1, 0.5))},
        "scan": {"size_um": [size, size], "offset_um": [float(rng.uniform(2, 8)), float(rng.uniform(2, 8))],
                 "pixels": pixels, "lines": pixels, "line_rate_hz": float(rng.uniform(1.5, 3.0))},
    })


def _stage(effects: dict):
    """The simulator's XY plant with the case's stage effects on (amplifier always on, no sensor noise)."""
    over = {}
    if "creep" in effects:
        over["creep_gamma"] = effects["creep"]
    if "drift" in effects:
        over["drift_rate_m_per_s"] = effects["drift"]
    if "dynamics" in effects:
        over.update(resonance_hz=effects["dynamics"], damping_ratio=DAMPING)
    c = effects.get("cross_coupling", 0.0)
    stage = default_stage("preisach", **over).with_effects(
        saturation=True, amplifier=True, creep="creep" in effects, drift="drift" in effects,
        resonance="dynamics" in effects, noise=False, coupling=c > 0)
    return replace(stage, coupling_x_to_y=c, coupling_y_to_x=c)


def simulate_images(scenario, effects: dict, seed: int) -> dict:
    """Trace/retrace of ``scenario`` scanned by the simulator with ``effects`` on; the ``.npz`` keys, with
    the Z loop's deflection images as ``error_trace``/``error_retrace`` (what an instrument file gives)."""
    g = scan_geometry(scenario)
    truth, _mesh = build_sample(scenario, g)
    surface = dilate(truth, mlct_tip("paraboloid", effects.get("tip", KNOWN_TIP_M)))
    stage = _stage(effects)
    controllers = [build_controller("none", None, None, nominal_sensitivity_m_per_V=a.params.sensitivity_m_per_V)
                   for a in (stage.x, stage.y)]
    zf = scenario.z_feedback
    loop = ZFeedback(ki_per_s=effects.get("z_feedback", zf.ki_per_s), kp=zf.kp, setpoint_m=zf.setpoint_nm * 1e-9,
                     deflection_noise_m=zf.deflection_noise_nm * 1e-9, loop_rate_hz=scenario.numerics.z_loop_rate_hz)
    z_stage = ZStage(sensitivity_m_per_V=scenario.z_stage.sensitivity_um_per_V * 1e-6,
                     max_voltage_V=scenario.z_stage.travel_um / scenario.z_stage.sensitivity_um_per_V,
                     hysteresis=scenario.z_stage.hysteresis)
    images = scan_frame(surface, raster_trajectory(g), stage, *controllers, z_stage, loop, np.random.default_rng(seed))
    return {"trace": images.trace.z, "retrace": images.retrace.z, "scan_size_m": g.size,
            "line_rate_hz": g.line_rate_hz, "scan_offset_m": g.offset, "error_trace": images.error_trace,
            "error_retrace": images.error_retrace, "error_channel": "deflection error (m)"}


def make_image_case(spec, rng: np.random.Generator, pixels: int = 64) -> dict:
    """One case: the model's scenario, the measured images (effects on) and the oracle's (effects off, same noise)."""
    effects = _effects(spec)
    scenario = _scenario(spec, effects, rng, pixels)
    seed = int(rng.integers(2**31))
    return {"spec": spec, "effects": effects, "scenario": scenario,
            "measured": simulate_images(scenario, effects, seed), "clean": simulate_images(scenario, {}, seed)}


_PARAM = {"creep": "gamma_per_decade", "drift": "rate_m_per_s", "cross_coupling": "coefficient",
          "tip": "apex_radius_m", "dynamics": "resonance_hz", "z_feedback": "ki_per_s"}


def _held_rms(design, fit) -> float:
    rec = design.record
    return float(np.sqrt(np.mean(design.rows(design.held, rec.trace - fit.trace, rec.retrace - fit.retrace) ** 2)))


def score_image_case(case: dict) -> dict:
    """Diagnose one case and score it against the truth and the oracle."""
    t0 = time.perf_counter()
    rep, _summary, _internals = diagnose_image_record(load_images(case["measured"]), case["scenario"])
    elapsed = time.perf_counter() - t0
    true, verdict = list(case["effects"]), rep["verdict"]
    out = {"effects": case["effects"], "sample": case["scenario"].sample.kind,
           "line_rate_hz": round(case["scenario"].scan.line_rate_hz, 3), "verdict": verdict,
           "ambiguous_with": {e["name"]: e["ambiguous_with"] for e in rep["effects"] if "ambiguous_with" in e},
           "seconds": round(elapsed, 2), "baseline_rms_gap_m": rep["baseline"]["rms_gap"], "status": rep["status"],
           "gap_to_noise": rep["baseline"]["gap_to_noise"], "implausible": [f["effect"] for f in rep["implausible"]]}
    out["top1"] = (verdict == []) if not true else (bool(verdict) and verdict[0] in true)
    out["exact"] = set(verdict) == set(true)
    if true:
        clean = build_design(load_images(case["clean"]), case["scenario"])
        oracle = 1.0 - _held_rms(clean, fit_image(clean)) / rep["baseline"]["rms_gap"]
        shrink = rep["final"]["heldout_shrink"] if verdict else 0.0
        out.update(oracle_shrink=round(oracle, 4), shrink=round(shrink, 4),
                   shrink_vs_oracle=round(shrink / oracle, 4) if oracle > 0.05 else None)
    found = {e["name"]: e["params"] for e in rep["effects"] if e["significant"]}
    out["params"] = {}
    for name in true:
        if name in found:
            ref, est = case["effects"][name], found[name][_PARAM[name]]
            out["params"][name] = {"true": ref, "estimated": est, "rel_error": round(abs(est - ref) / abs(ref), 4)}
    return out


def validate_image_diagnosis(n_cases: int = 32, seed: int = 0, pixels: int = 64) -> dict:
    """Run ``n_cases`` simulated image cases (6 effects × 3 magnitudes, 6 pairs, nulls) of ``pixels`` ×
    ``pixels`` and score them."""
    if n_cases < 1:
        raise ValueError("n_cases must be >= 1")
    if not 32 <= pixels <= 256:
        raise ValueError(f"pixels must be in [32, 256], got {pixels}")
    rng = np.random.default_rng(seed)
    cases = [score_image_case(make_image_case(spec, np.random.default_rng(rng.integers(2**63)), pixels))
             for spec in image_case_plan(n_cases)]
    nulls = [c for c in cases if not c["effects"]]
    eff = [c for c in cases if c["effects"]]
    rel = [p["rel_error"] for c in cases for p in c["params"].values()]
    ratios = [c["shrink_vs_oracle"] for c in eff if c.get("shrink_vs_oracle") is not None]
    detectable = [c for c in eff if c.get("oracle_shrink", 1.0) >= 0.1]  # the true effect explains ≥ 10 % of the gap
    by_effect = {}
    for name in IMAGE_MAGNITUDES:
        sub = [c for c in eff if list(c["effects"]) == [name]]
        errs = [c["params"][name]["rel_error"] for c in sub if name in c["params"]]
        by_effect[name] = {"cases": len(sub), "top1": float(np.mean([c["top1"] for c in sub])) if sub else None,
                           "param_median_rel_error": float(np.median(errs)) if errs else None}
    return {
        "n_cases": len(cases), "seed": seed, "pixels": pixels,
        "top1_accuracy": float(np.mean([c["top1"] for c in cases])),
        "top1_accuracy_effect_cases": float(np.mean([c["top1"] for c in eff])) if eff else None,
        "top1_accuracy_detectable": float(np.mean([c["top1"] for c in detectable + nulls])),
        "undetectable_cases": len(eff) - len(detectable),
        "exact_set_accuracy": float(np.mean([c["exact"] for c in cases])),
        "null_cases": len(nulls),
        "false_alarm_rate": float(np.mean([bool(c["verdict"]) for c in nulls])) if nulls else None,
        "null_status_counts": {k: sum(c["status"] == k for c in nulls) for k in STATUSES},
        "param_cases": len(rel),
        "param_median_rel_error": float(np.median(rel)) if rel else None,
        "param_within_25pct": float(np.mean(np.asarray(rel) <= 0.25)) if rel else None,
        "shrink_vs_oracle_median": float(np.median(ratios)) if ratios else None,
        "shrink_vs_oracle_mean": float(np.mean(ratios)) if ratios else None,
        "seconds_per_case_median": float(np.median([c["seconds"] for c in cases])),
        "by_effect": by_effect,
        "targets": {"top1_accuracy": 0.9, "false_alarm_rate": 0.1, "shrink_vs_oracle": 0.7, "param_rel_error": 0.25},
        "cases": cases,
    }
