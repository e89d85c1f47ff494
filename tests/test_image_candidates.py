"""Image candidates that real forward/backward pairs call for, tested on scans made by other code.

``z_bow`` (a smooth height background that differs between trace and retrace) is fitted as
Legendre terms of the intended x; here the effect comes from the simulator's own Z stage
(:class:`afmsim.scan.ZStage`, a Bouc–Wen element under the PI loop, :func:`afmsim.scan.scan_frame`)
scanning a lens array on a 1° tilted sample, so each line sweeps the Z range and trace and retrace
run the two branches of the Z loop. The Bouc–Wen β, γ are raised from the simulator's defaults
(< 1 % loop width at sub-µm excursions) to a loop of ~2 % of the range swept: the datasheet's
small-signal piezo hysteresis. The null is the same scan with a linear Z stage.
"""

import numpy as np
import pytest

from afmsim.compensation import build_controller
from afmsim.diagnosis.images.attribute import diagnose_image_record
from afmsim.diagnosis.images.record import load_images
from afmsim.diagnosis.plausible import implausible
from afmsim.experiment import build_sample, scan_geometry
from afmsim.scan import ZFeedback, ZStage, raster_trajectory, scan_frame
from afmsim.scenario import parse_scenario
from afmsim.stage import default_stage
from afmsim.tip import dilate, mlct_tip

SMALL_SIGNAL_BW = {"bw_alpha": 0.22, "bw_beta_per_V": 0.5, "bw_gamma_per_V": 0.2}


def _tilted_lens_scan(z_hysteresis: bool, seed: int, tilt_deg: float = 1.0) -> dict:
    """Trace/retrace (the ``.npz`` keys) of a lens array tilted along x, simulator's XY plant uncompensated."""
    scenario = parse_scenario({
        "sample": {"kind": "microlens", "diameter_um": 5.0, "sag_um": 0.4, "pitch_um": 7.5},
        "tip": {"shape": "paraboloid", "apex_radius_nm": 20},
        "scan": {"size_um": [16, 16], "offset_um": [4, 4], "pixels": 64, "lines": 64, "line_rate_hz": 2.0}})
    geometry = scan_geometry(scenario)
    truth, _mesh = build_sample(scenario, geometry)
    tilt = np.tan(np.radians(tilt_deg)) * (truth.x - truth.x.mean())
    surface = dilate(truth.with_z(truth.z + tilt[None, :]), mlct_tip("paraboloid", 20e-9))
    stage = default_stage("preisach").with_effects(saturation=True, amplifier=True, creep=False, drift=False,
                                                   resonance=False, noise=False, coupling=False)
    controllers = [build_controller("none", None, None, nominal_sensitivity_m_per_V=a.params.sensitivity_m_per_V)
                   for a in (stage.x, stage.y)]
    loop = ZFeedback(ki_per_s=3000.0, kp=0.1, setpoint_m=20e-9, deflection_noise_m=0.3e-9,
                     loop_rate_hz=scenario.numerics.z_loop_rate_hz)
    z_stage = ZStage(hysteresis=z_hysteresis, **SMALL_SIGNAL_BW)
    images = scan_frame(surface, raster_trajectory(geometry), stage, *controllers, z_stage, loop,
                        np.random.default_rng(seed))
    return {"trace": images.trace.z, "retrace": images.retrace.z, "scan_size_m": geometry.size,
            "line_rate_hz": geometry.line_rate_hz}


@pytest.fixture(scope="module")
def z_hysteresis_pair():
    return [diagnose_image_record(load_images(_tilted_lens_scan(h, seed=21)))[0] for h in (True, False)]


def _bow(report):
    return next(e for e in report["effects"] if e["name"] == "z_bow")


def test_z_stage_hysteresis_on_a_tilted_sample_is_named_z_bow(z_hysteresis_pair):
    report, _null = z_hysteresis_pair
    assert report["images"]["reference"] == "trace"
    assert report["verdict"][:1] == ["z_bow"], report["verdict"]
    params = _bow(report)["params"]
    assert 0.005 <= params["share_of_line_z_range"] <= 0.1 and not implausible("z_bow", params)
    assert report["final"]["heldout_shrink"] >= 0.2
    assert report["status"] in ("explained", "partly_explained")


def test_z_bow_is_not_named_on_a_linear_z_stage(z_hysteresis_pair):
    report, null = z_hysteresis_pair
    assert "z_bow" not in null["verdict"]
    assert _bow(null)["params"]["difference_ptp_m"] < 0.3 * _bow(report)["params"]["difference_ptp_m"]


def test_an_implausibly_large_bow_is_flagged():
    assert implausible("z_bow", {"share_of_line_z_range": 0.4, "difference_ptp_m": 4e-8})
    assert not implausible("z_bow", {"share_of_line_z_range": 0.03, "difference_ptp_m": 4e-8})


def test_a_gap_in_a_few_lines_is_located_there():
    """A glitch in one line of forty (a tip jump) holds most of the gap; white noise spreads over all lines."""
    from afmsim.diagnosis.images.localise import localise_image

    rng = np.random.default_rng(3)
    model = np.cumsum(np.ones((40, 30)), axis=1)
    noise = rng.normal(size=(40, 30))
    glitch = noise.copy()
    glitch[7, 10:20] += 25.0
    held = np.ones(40, dtype=bool)
    spread = localise_image(noise, noise, model, model, (model, model), held)["lines"]["worst"]
    event = localise_image(glitch, noise, model, model, (model, model), held)["lines"]["worst"]
    assert spread["sample_fraction"] == pytest.approx(0.05, abs=0.01)
    assert spread["share"] < 0.15 < 0.6 < event["share"]


def test_line_offsets_between_the_directions_are_measured_not_scored():
    """Random per-line offsets (σ 2 nm, datasheet 0.5–5 nm) on the retrace of a tilted grating that changes
    along y: the jitter is recovered; without them it reads below the datasheet's range."""
    from afmsim.diagnosis.images.attribute import line_offsets

    rng = np.random.default_rng(8)
    x, y = np.meshgrid(np.linspace(0, 1, 96), np.linspace(0, 1, 80))
    topo = 100e-9 * (np.sin(2 * np.pi * 6 * (x + 0.3 * y)) > 0) + 300e-9 * y + 40e-9 * x
    trace = topo + 0.2e-9 * rng.standard_normal(topo.shape)
    retrace = topo + 0.2e-9 * rng.standard_normal(topo.shape) - 5e-9
    base = load_images({"trace": trace, "retrace": retrace, "scan_size_m": (5e-6, 5e-6), "line_rate_hz": 1.0})
    jumped = load_images({"trace": trace, "retrace": retrace + 2e-9 * rng.standard_normal((80, 1)),
                          "scan_size_m": (5e-6, 5e-6), "line_rate_hz": 1.0})
    lines = np.ones(80, dtype=bool)
    assert line_offsets(base, lines)["jitter_m"] < 0.2e-9
    assert line_offsets(base, lines)["retrace_minus_trace_m"] == pytest.approx(-5e-9, abs=0.1e-9)
    assert line_offsets(jumped, lines)["jitter_m"] == pytest.approx(2e-9, rel=0.3)
