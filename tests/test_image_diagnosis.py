"""Image-data diagnosis: input validation, forward-model pieces, diagnosed scans, CLI, a small validation run."""

import json

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from afmsim.cli import app
from afmsim.diagnosis import diagnose_images, load_images, validate_image_diagnosis
from afmsim.diagnosis.images.model import Layout, ZLoop
from afmsim.diagnosis.images.record import MIN_LINES
from afmsim.diagnosis.images.reference import Surface, parabolic_dilation
from afmsim.diagnosis.images.validation import image_case_plan, make_image_case
from afmsim.report.gwy import write_gwy
from afmsim.samples.heightmap import HeightMap

runner = CliRunner()


def _pair(lines=20, pixels=24, seed=0):
    rng = np.random.default_rng(seed)
    trace = 1e-7 * rng.standard_normal((lines, pixels))
    return {"trace": trace, "retrace": trace + 1e-9, "scan_size_m": (10e-6, 8e-6), "line_rate_hz": 2.0}


@pytest.fixture(scope="module")
def z_case():
    """A grating scanned with a Z loop ten times slower than its scenario says (ki 600 vs 3000 1/s)."""
    return make_image_case(("z_feedback", 1), np.random.default_rng(5), pixels=40)


def test_bad_images_are_refused_with_one_line(tmp_path):
    good = _pair()
    cases = {
        "lack key(s)": {k: v for k, v in good.items() if k != "retrace"},
        "shapes differ": {**good, "retrace": good["retrace"][:, :-1]},
        "run of NaN": {**good, "trace": np.where(np.arange(24) < 2, np.nan, good["trace"])},
        "no finite pixel": {**good, "retrace": np.where(np.arange(20)[:, None] == 3, np.nan, good["retrace"])},
        "too small": {**good, "trace": good["trace"][:8], "retrace": good["retrace"][:8]},
        "scan_size_m": {**good, "scan_size_m": (-1e-6, 8e-6)},
        "line_rate_hz": {**good, "line_rate_hz": 0.0},
    }
    for fragment, data in cases.items():
        with pytest.raises(ValueError) as info:
            load_images(data)
        assert fragment in str(info.value) and "\n" not in str(info.value)
    (tmp_path / "x.txt").write_text("1")
    with pytest.raises(ValueError, match="must be .npz or .gwy"):
        load_images(tmp_path / "x.txt")
    with pytest.raises(ValueError, match="not found"):
        load_images(tmp_path / "missing.npz")
    holed = good["trace"].copy()
    holed[5, 10] = np.nan
    rec = load_images({**good, "trace": holed})
    assert rec.filled_pixels == 1 and np.isfinite(rec.trace).all()
    assert rec.trace[5, 10] == pytest.approx(0.5 * (holed[5, 9] + holed[5, 11]))


def test_a_frame_stopped_early_is_diagnosed_on_the_lines_it_scanned(tmp_path):
    """Lines never scanned at the frame's end — zero-filled, NaN, or cut short by a NaN run — are dropped
    with their share of the scan height (and the error signal's lines with them); the same hole in a
    line the frame goes on after is still refused, and so is a frame with too few scanned lines."""
    good = _pair(lines=40)
    trace, retrace = good["trace"].copy(), good["retrace"].copy()
    trace[30:] = 0.0  # the instrument's fill
    retrace[32:] = np.nan
    retrace[29, 15:] = np.nan  # stopped within line 29's retrace
    errors = {"error_trace": np.ones((40, 24)) + trace, "error_retrace": np.ones((40, 24))}
    rec = load_images({**good, "trace": trace, "retrace": retrace, **errors})
    assert rec.shape == (29, 24) and rec.unscanned_lines == 11 and rec.error_trace.shape == (29, 24)
    assert rec.scan_size_m == pytest.approx((10e-6, 8e-6 * 29 / 40)) and np.array_equal(rec.trace, trace[:29])
    middle = retrace.copy()
    middle[29, 15:] = good["retrace"][29, 15:]
    middle[10, 3:6] = np.nan
    with pytest.raises(ValueError, match="line 10 has a run of NaN"):
        load_images({**good, "trace": trace, "retrace": middle})
    short = good["trace"].copy()
    short[MIN_LINES - 1:] = np.nan  # 15 lines scanned: fewer than the diagnosis needs
    with pytest.raises(ValueError, match="no finite pixel"):
        load_images({**good, "trace": short})
    report, summary = diagnose_images({**good, "trace": trace, "retrace": retrace})
    assert report["images"]["unscanned_lines"] == 11 and report["images"]["lines"] == 29
    assert summary.startswith("Frame stopped early: the last 11 of 40 lines hold no scan")


def test_gwy_channels_and_run_images_npz_load(tmp_path):
    pair = _pair()
    maps = {k: HeightMap(pair[k], (10e-6 / 24, 8e-6 / 20), (1e-6, 2e-6)) for k in ("trace", "retrace")}
    path = write_gwy(tmp_path / "scan.gwy", maps)
    with pytest.raises(ValueError, match="line rate"):
        load_images(path)
    rec = load_images(path, line_rate_hz=3.0)
    assert np.allclose(rec.trace, pair["trace"]) and np.allclose(rec.scan_size_m, (10e-6, 8e-6))
    assert np.allclose(rec.scan_offset_m, (1e-6 - 10e-6 / 48, 2e-6 - 8e-6 / 40)) and rec.line_rate_hz == 3.0
    # the keys `afmsim run` writes into images.npz, with the scenario beside it for the line rate
    run = tmp_path / "run"
    run.mkdir()
    np.savez(run / "images.npz", trace_spi=pair["trace"], retrace_spi=pair["retrace"], trace_none=-pair["trace"],
             retrace_none=-pair["retrace"], image_pixel_size_m=[10e-6 / 24, 8e-6 / 20], image_origin_m=[1e-6, 2e-6])
    with pytest.raises(ValueError, match="line rate unknown"):
        load_images(run / "images.npz")
    (run / "scenario.yaml").write_text(yaml.safe_dump({"sample": {"kind": "grating"}, "scan": {"line_rate_hz": 1.5}}))
    rec = load_images(run / "images.npz")
    assert np.allclose(rec.trace, -pair["trace"]) and rec.line_rate_hz == 1.5 and rec.source.endswith("[none]")
    assert np.allclose(load_images(run / "images.npz", channel="spi").trace, pair["trace"])
    with pytest.raises(ValueError, match="available controllers"):
        load_images(run / "images.npz", channel="diapi")


def test_gwy_with_afmsim_line_rate_metadata_needs_no_scenario(tmp_path):
    """The ``line rate (Hz)`` that ``afmsim run`` writes into images.gwy is read back."""
    pair = _pair()
    maps = {k: HeightMap(pair[k], (10e-6 / 24, 8e-6 / 20), (1e-6, 2e-6)) for k in ("trace", "retrace")}
    path = write_gwy(tmp_path / "scan.gwy", maps, meta={"line rate (Hz)": repr(2.5)})
    assert load_images(path).line_rate_hz == pytest.approx(2.5)
    assert load_images(path, line_rate_hz=3.0).line_rate_hz == 3.0        # --scenario still wins


def test_truncated_npz_is_one_line_and_exit_2(tmp_path):
    good = tmp_path / "good.npz"
    np.savez(good, **_pair())
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(ValueError, match="not a readable .npz"):
        load_images(cut)
    out = tmp_path / "diag"
    outcome = CliRunner().invoke(app, ["diagnose", "--measured", str(cut), "--out", str(out)])
    assert outcome.exit_code == 2 and "Traceback" not in outcome.output and not out.exists()
    assert len([line for line in outcome.output.splitlines() if line.strip()]) == 1


def test_z_loop_lag_and_parachuting():
    dt, ki, kp, sp = 1e-4, 500.0, 0.1, 20e-9
    loop = ZLoop(ki, kp, sp)
    up = np.r_[np.zeros(50), np.full(400, 100e-9)]
    h, _ = loop.run(up, None, dt)
    tau = (1 + kp) / ki  # closed-loop time constant while in contact
    k = 50 + int(round(tau / dt))
    assert h[k] == pytest.approx(100e-9 * (1 - np.exp(-1) / (1 + kp)), rel=0.05)  # h = s·(1 − e^(−t/τ)/(1 + kp))
    assert h[-1] == pytest.approx(100e-9, rel=1e-3)
    down, _ = loop.run(up[::-1].copy(), None, dt)
    fall = -np.diff(down[402:420]) / dt  # tip off the surface: the integrator falls at ki·setpoint
    assert np.allclose(fall, ki * sp, rtol=0.02)
    smooth = np.sin(np.linspace(0, 6, 300)) * 1e-7
    fast, _ = ZLoop(1e6, kp, sp).run(smooth, None, 1e-4)  # a stiff loop records the surface (interior samples)
    assert np.max(np.abs(fast - smooth)[1:-1]) < 5e-11


def test_parabolic_dilation_composes_and_surface_gradient_is_exact():
    z = np.zeros((41, 41))
    z[20, 20] = 1e-6
    spike = HeightMap(z, (10e-9, 10e-9))
    one = parabolic_dilation(spike, 50e-9)
    r2 = ((np.arange(41) - 20) * 10e-9) ** 2
    expected = np.maximum(1e-6 - (r2[:, None] + r2[None, :]) / (2 * 50e-9), 0.0)
    assert np.allclose(one.z, expected, atol=1e-12)
    # paraboloids compose, P_20nm ⊕ P_30nm = P_50nm, to the grid's (dx/2)²·(1/R1 + 1/R2) (x and y each half)
    assert np.allclose(parabolic_dilation(parabolic_dilation(spike, 20e-9), 30e-9).z, one.z, atol=2.1e-9)
    rng = np.random.default_rng(1)
    surf = Surface(HeightMap(rng.standard_normal((9, 11)) * 1e-8, (1e-7, 2e-7), (0.0, 0.0)))
    x, y = rng.uniform(0.1e-7, 9.9e-7, 50), rng.uniform(0.1e-7, 15.9e-7, 50)
    s, gx, gy = surf.sample(x, y)
    eps = 1e-12
    assert np.allclose((surf.sample(x + eps, y, gradient=False)[0] - s) / eps, gx, rtol=1e-4, atol=1e-4)
    assert np.allclose((surf.sample(x, y + eps, gradient=False)[0] - s) / eps, gy, rtol=1e-4, atol=1e-4)


def test_layout_mirrors_retrace_onto_trace():
    lay = Layout((3, 5), (5e-6, 3e-6), (1e-6, 0.0), 2.0, 0.5, subsamples=2)
    rt = lay.retrace
    assert rt.sum() == lay.n // 2 and np.allclose(lay.u[lay.mirror[rt]], lay.u[rt])
    assert np.all(lay.line[lay.mirror] == lay.line)
    trace, retrace = lay.images(lay.u)
    assert np.allclose(trace, lay.geometry.pixel_centres_x) and np.allclose(retrace, trace)
    assert np.all(np.diff(lay.t) > 0) and lay.t[0] == 0.0


def test_diagnosis_finds_a_slow_z_loop(z_case, tmp_path):
    report, summary = diagnose_images(z_case["measured"], scenario=z_case["scenario"], figure_path=tmp_path / "d.png")
    json.dumps(report)
    assert report["images"]["reference"] == "scenario" and report["baseline"]["unit"] == "m"
    assert {"direction", "axis", "features", "position", "time"} <= set(report["where"])
    assert {e["name"] for e in report["effects"]} == {"creep", "drift", "dynamics", "cross_coupling", "tip", "z_feedback",
                                                        "z_bow"}
    for e in report["effects"]:
        assert {"name", "params", "heldout_shrink", "significant"} <= set(e)
    assert report["verdict"][:1] == ["z_feedback"]
    ki = next(e for e in report["effects"] if e["name"] == "z_feedback")["params"]["ki_per_s"]
    assert ki == pytest.approx(600.0, rel=0.25)
    assert report["final"]["heldout_shrink"] > 0.5 and "Verdict" in summary
    assert (tmp_path / "d.png").stat().st_size > 1000


def test_trace_reference_says_what_it_cannot_see(z_case):
    report, _ = diagnose_images(z_case["measured"])
    assert report["images"]["reference"] == "trace"
    assert set(report["not_identifiable"]) == {"drift", "cross_coupling", "tip"}
    assert {e["name"] for e in report["effects"]} <= {"creep", "dynamics", "z_feedback", "z_bow"}
    assert report["baseline"]["rms_gap"] > 0


def test_cli_diagnoses_images_and_refuses_bad_ones(z_case, tmp_path):
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(yaml.safe_dump(z_case["scenario"].model_dump(mode="json")))
    good = tmp_path / "scan.npz"
    np.savez(good, **{k: np.asarray(v) for k, v in z_case["measured"].items()})
    out = tmp_path / "diag"
    result = runner.invoke(app, ["diagnose", "--measured", str(good), "--scenario", str(scenario), "--out", str(out)])
    assert result.exit_code == 0, result.output
    report = json.loads((out / "diagnosis.json").read_text())
    assert report["verdict"][:1] == ["z_feedback"] and "Verdict" in result.output
    assert {"diagnosis.png", "summary.txt", "manifest.json"} <= {p.name for p in out.iterdir()}
    bad = tmp_path / "bad.npz"
    arrays = {k: np.asarray(v) for k, v in z_case["measured"].items()}
    np.savez(bad, **{**arrays, "retrace": arrays["retrace"][:-3]})
    result = runner.invoke(app, ["diagnose", "--measured", str(bad), "--out", str(tmp_path / "nope")])
    assert result.exit_code == 2 and "shapes differ" in result.output and not (tmp_path / "nope").exists()
    assert len(result.output.strip().splitlines()) == 1
    result = runner.invoke(app, ["validate-diagnosis", "--kind", "pictures"])
    assert result.exit_code == 2 and "--kind" in result.output
    run = tmp_path / "run"  # a run folder stands for its images.npz
    run.mkdir()
    result = runner.invoke(app, ["diagnose", "--measured", str(run), "--out", str(tmp_path / "nope")])
    assert result.exit_code == 2 and "a folder without images.npz" in result.output
    np.savez(run / "images.npz", trace_none=arrays["trace"], retrace_none=arrays["retrace"],
             image_pixel_size_m=[1e-7, 1e-7])  # no scenario.yaml beside it: no line rate
    result = runner.invoke(app, ["diagnose", "--measured", str(run), "--out", str(tmp_path / "nope")])
    assert result.exit_code == 2 and "images.npz: line rate unknown" in result.output, result.output
    assert not (tmp_path / "nope").exists()


def test_small_image_validation():
    plan = image_case_plan(32)
    assert len(plan) == 32 and sum(k == "null" for k, _ in plan) >= 6 and sum(k == "pair" for k, _ in plan) == 6
    scores = validate_image_diagnosis(n_cases=4, seed=11, pixels=40)
    assert scores["n_cases"] == 4 and scores["null_cases"] >= 1
    assert scores["top1_accuracy"] >= 0.75 and scores["false_alarm_rate"] == 0.0
    assert scores["param_within_25pct"] is None or scores["param_within_25pct"] >= 0.5


def test_loop_diagnosis_takes_modelled_effects_from_the_scenario(tmp_path):
    t = np.linspace(0.0, 4.0, 2001)
    v = 5 - 4 * np.cos(np.pi * t)  # a 0.5 Hz loop with a lagging extra term
    csv = tmp_path / "loop.csv"
    rows = np.column_stack([t, v, 1.1e-6 * v + 0.2e-6 * np.sin(np.pi * t)])
    csv.write_text("t_s,v_V,x_m\n" + "\n".join(",".join(f"{a:.9g}" for a in r) for r in rows) + "\n")
    scenario = tmp_path / "s.yaml"
    scenario.write_text(yaml.safe_dump({"sample": {"kind": "grating"},
                                        "stage": {"creep": True, "drift": False, "dynamics": False, "cross_coupling": 0.0}}))
    out = tmp_path / "diag"
    result = runner.invoke(app, ["diagnose", "--measured", str(csv), "--scenario", str(scenario), "--out", str(out)])
    assert result.exit_code == 0, result.output
    report = json.loads((out / "diagnosis.json").read_text())
    assert report["baseline"]["modelled"] == ["creep"] and "creep" not in report["verdict"]
    assert "creep" not in {e["name"] for e in report["effects"]} and {"drift", "dynamics"} <= {e["name"] for e in report["effects"]}
    bad = tmp_path / "bad.yaml"
    bad.write_text("sample: {kind: grating}\nstage: {creep: maybe}\n")
    result = runner.invoke(app, ["diagnose", "--measured", str(csv), "--scenario", str(bad), "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "stage.creep" in result.output and not (tmp_path / "x").exists()


def test_large_images_are_cut_to_the_budget_first_lines_and_pixel_block_means():
    from afmsim.diagnosis.images.record import within_budget

    rng = np.random.default_rng(2)
    trace, retrace = rng.normal(size=(300, 1040)), rng.normal(size=(300, 1040))
    rec = load_images({"trace": trace, "retrace": retrace, "scan_size_m": (5.2e-6, 3e-6), "line_rate_hz": 1.0})
    cut, done = within_budget(rec)
    assert cut.shape == (256, 346) and done["pixels_per_bin"] == 3 and done["pixels_used"] == 1038
    np.testing.assert_allclose(cut.trace, trace[:256, :1038].reshape(256, 346, 3).mean(axis=2))
    np.testing.assert_allclose(cut.retrace[:, 0], retrace[:256, :3].mean(axis=1))
    assert cut.scan_size_m == pytest.approx((5.2e-6 * 1038 / 1040, 3e-6 * 256 / 300))
    lines_only, done = within_budget(load_images({"trace": trace[:, :512], "retrace": retrace[:, :512],
                                                  "scan_size_m": (5.2e-6, 3e-6), "line_rate_hz": 1.0}))
    assert lines_only.shape == (256, 512) and done["pixels_per_bin"] == 1  # 512 pixels: lines cut, pixels kept
    assert cut.line_rate_hz == rec.line_rate_hz  # the fast axis's speed is kept
    assert within_budget(load_images(_pair()))[1] is None


def test_diagnosis_of_a_large_image_is_the_diagnosis_of_its_cut(z_case, monkeypatch):
    import afmsim.diagnosis.images.record as record_module
    from afmsim.diagnosis.images.record import within_budget

    rec = load_images(z_case["measured"])
    monkeypatch.setattr(record_module, "MAX_LINES", rec.shape[0] - 4)
    monkeypatch.setattr(record_module, "MAX_PIXELS", rec.shape[1] // 2)
    report, summary = diagnose_images(rec)
    cut, done = within_budget(rec)
    assert report["images"]["cut"] == done and (report["images"]["lines"], report["images"]["pixels"]) == cut.shape
    assert summary.startswith(f"Image cut to the diagnosis's {rec.shape[0] - 4} lines × {rec.shape[1] // 2} pixels: "
                              f"the first {rec.shape[0] - 4} of {rec.shape[0]} lines; pixels averaged in blocks of 2")
    assert "not proof that nothing is missing" in summary.splitlines()[0]
    monkeypatch.setattr(record_module, "MAX_LINES", 10**6)
    direct, _ = diagnose_images(cut)
    assert direct["baseline"]["rms_gap"] == pytest.approx(report["baseline"]["rms_gap"], rel=1e-9)
    assert direct["status"] == report["status"] and direct["verdict"] == report["verdict"]


def test_reverse_lines_puts_a_flipped_file_back_in_scan_order(z_case, tmp_path):
    """A file stored last-scanned first (as an import may flip a frame) reads back in scan order with
    --reverse-lines: the same record, hence the same diagnosis, as the file in scan order."""
    arrays = {k: np.asarray(v) for k, v in z_case["measured"].items()}
    flipped = tmp_path / "flipped.npz"
    np.savez(flipped, **{**arrays, "trace": arrays["trace"][::-1], "retrace": arrays["retrace"][::-1]})
    record = load_images(flipped, reverse_lines=True)
    assert np.array_equal(record.trace, arrays["trace"]) and np.array_equal(record.retrace, arrays["retrace"])
    assert "(lines reversed)" in record.source
    assert np.array_equal(load_images(flipped).trace, arrays["trace"][::-1])
    from_dict = load_images({**arrays, "trace": arrays["trace"][::-1], "retrace": arrays["retrace"][::-1]},
                            reverse_lines=True)
    assert np.array_equal(from_dict.retrace, arrays["retrace"])
    with pytest.raises(ValueError, match="reverse_lines"):
        load_images(record, reverse_lines=True)
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(yaml.safe_dump(z_case["scenario"].model_dump(mode="json")))
    expected, _ = diagnose_images(z_case["measured"], scenario=z_case["scenario"])
    out = tmp_path / "diag"
    result = runner.invoke(app, ["diagnose", "--measured", str(flipped), "--scenario", str(scenario), "--out", str(out),
                                 "--reverse-lines"])
    assert result.exit_code == 0, result.output
    report = json.loads((out / "diagnosis.json").read_text())
    assert report["baseline"]["rms_gap"] == pytest.approx(expected["baseline"]["rms_gap"], rel=1e-9)
    assert report["verdict"] == expected["verdict"]
    assert json.loads((out / "manifest.json").read_text())["config"]["reverse_lines"] is True
    csv = tmp_path / "loop.csv"
    csv.write_text("t_s,v_V,x_m\n0,0,0\n1,1,1e-9\n")
    result = runner.invoke(app, ["diagnose", "--measured", str(csv), "--reverse-lines", "--out", str(tmp_path / "no")])
    assert result.exit_code == 2 and "--reverse-lines goes with an image file" in result.output
    assert len(result.output.strip().splitlines()) == 1 and not (tmp_path / "no").exists()
