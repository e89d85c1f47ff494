"""The command line: scenarios validated up front, bad input → exit 2 and one line, atomic run folders."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from afmsim.cli import app
from afmsim.experiment import run_scenario
from afmsim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()


@pytest.mark.parametrize("name", ["quick", "microlens", "grating", "grating_full_range"])
def test_bundled_scenarios_validate(name):
    result = runner.invoke(app, ["validate", str(ROOT / "scenarios" / f"{name}.yaml")])
    assert result.exit_code == 0, result.output
    assert "valid" in result.output


BAD = [
    ({"scan": {"pixels": 4}}, "scan.pixels: must be in [16, 2048]"),
    ({"scan": {"size_um": [500, 10]}}, "scan.size_um.0: must be in [0.1, 100] µm"),
    ({"sample": {"kind": "microlens", "diameter_um": -3}}, "sample.diameter_um: must be in [0.5, 50] µm"),
    ({"z_feedback": {"ki_per_s": "fast"}}, "z_feedback.ki_per_s"),
    ({"controllers": ["magic"]}, "controllers.0"),
    ({"colour": "blue"}, "colour: Extra inputs are not permitted"),
    ({"stage": {"hysteresis": "maxwell"}}, "stage.hysteresis"),
]


def _write(tmp_path, overrides):
    data = yaml.safe_load((ROOT / "scenarios" / "quick.yaml").read_text())
    for key, value in overrides.items():
        data[key] = {**data[key], **value} if isinstance(value, dict) and isinstance(data.get(key), dict) else value
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize("overrides, message", BAD)
def test_bad_scenarios_exit_2_with_one_line_naming_the_field(tmp_path, overrides, message):
    path = _write(tmp_path, overrides)
    for command in (["validate", str(path)], ["run", str(path), "--out", str(tmp_path / "run")]):
        result = runner.invoke(app, command)
        assert result.exit_code == 2
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], result.output
        assert "Traceback" not in result.output
    assert not (tmp_path / "run").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["bad.yaml"]          # no half-written output


def test_unreadable_and_invalid_yaml_files(tmp_path):
    result = runner.invoke(app, ["validate", str(tmp_path / "missing.yaml")])
    assert result.exit_code == 2 and "cannot read" in result.output
    broken = tmp_path / "broken.yaml"
    broken.write_text("scan: [unclosed\n")
    result = runner.invoke(app, ["validate", str(broken)])
    assert result.exit_code == 2 and "not valid YAML" in result.output


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "quick"
    result = runner.invoke(app, ["run", str(ROOT / "scenarios" / "quick.yaml"), "--out", str(out), "--experiments", "1"])
    assert result.exit_code == 0, result.output
    return out, result.output


def test_run_writes_images_metrics_and_manifest(quick_run):
    out, output = quick_run
    metrics = json.loads((out / "metrics.json").read_text())
    for name in ("none", "spi", "diapi", "ideal"):
        scores = metrics["controllers"][name]
        assert {"mean", "std", "per_experiment"} <= set(scores["nsl2"])
        assert np.isfinite(scores["shift_x_m"]["mean"])
        assert (out / f"image_{name}.png").stat().st_size > 10_000
    assert "e_D" in metrics
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["seed"] == 7 and manifest["config"]["name"] == "quick"
    assert {"numpy", "scipy", "afmsim"} <= set(manifest["versions"])
    assert "commit" in manifest["git"]
    with np.load(out / "images.npz") as arrays:
        assert arrays["trace_none"].shape == (64, 64) and arrays["retrace_diapi"].shape == (64, 64)
    assert "e_D" in output
    assert "experiment 1/1" not in output          # no progress bar when output is not a terminal


def test_python_api_twin_gives_the_same_arrays(quick_run):
    out, _ = quick_run
    scenario = load_scenario(ROOT / "scenarios" / "quick.yaml").model_copy(update={"experiments": 1})
    result = run_scenario(scenario)
    with np.load(out / "images.npz") as arrays:
        for name, images in result.images.items():
            np.testing.assert_array_equal(arrays[f"trace_{name}"], images.trace.z)
            np.testing.assert_array_equal(arrays[f"retrace_{name}"], images.retrace.z)


def test_run_refuses_an_existing_output_folder(quick_run):
    out, _ = quick_run
    result = runner.invoke(app, ["run", str(ROOT / "scenarios" / "quick.yaml"), "--out", str(out)])
    assert result.exit_code == 2 and "already exists" in result.output


def test_identify_writes_tables_and_json(tmp_path):
    out = tmp_path / "identify"
    result = runner.invoke(app, ["identify", "--out", str(out), "--experiments", "2"])
    assert result.exit_code == 0, result.output
    assert "Table 1 analogue" in result.output and "Table 2 analogue" in result.output
    data = json.loads((out / "identify.json").read_text())
    for name in ("spi", "diapi", "iiapi", "capi"):
        assert len(data["models"][name]["rms_V"]["per_experiment"]) == 2
        assert {"mean", "std"} <= set(data["models"][name]["max_V"])
        assert data["models"][name]["params"]
    assert (out / "loops.csv").read_text().startswith("t_s,voltage_V,displacement_m")


def test_diagnose_writes_report_and_rejects_bad_records(tmp_path):
    t = np.arange(2000) / 500.0
    v = 5 + 4 * np.sin(2 * np.pi * t)
    x = 10e-6 * v / 9.1 + 0.3e-6 * np.sin(2 * np.pi * t - 0.3)
    good = tmp_path / "loop.csv"
    np.savetxt(good, np.column_stack([t, v, x]), delimiter=",", header="t_s,v_V,x_m", comments="")
    out = tmp_path / "diag"
    result = runner.invoke(app, ["diagnose", "--measured", str(good), "--out", str(out)])
    assert result.exit_code == 0, result.output
    report = json.loads((out / "diagnosis.json").read_text())
    assert {"baseline", "where", "effects", "verdict"} <= set(report)
    assert (out / "diagnosis.png").exists()
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,v_V\n0,1\n1,2\n")
    result = runner.invoke(app, ["diagnose", "--measured", str(bad), "--out", str(tmp_path / "nope")])
    assert result.exit_code == 2 and "x_m" in result.output and not (tmp_path / "nope").exists()
    result = runner.invoke(app, ["diagnose", "--measured", str(tmp_path / "scan.npz"), "--out", str(tmp_path / "no")])
    assert result.exit_code == 2 and "image file not found" in result.output and not (tmp_path / "no").exists()


def test_a_grating_scan_too_narrow_for_the_pitch_scores_still_runs(tmp_path):
    """6 µm of a 5 µm-period grating: no complete period in a half field. NSL2 and shift are scored,
    the pitch scores are left out with a note naming them, exit 0."""
    scenario = {"name": "narrow-grating", "seed": 3, "experiments": 1, "sample": {"kind": "grating"},
                "scan": {"size_um": [6.0, 6.0], "offset_um": [2.0, 2.0], "pixels": 32, "lines": 16},
                "controllers": ["none"]}
    path = tmp_path / "narrow.yaml"
    path.write_text(yaml.safe_dump(scenario))
    result = runner.invoke(app, ["run", str(path), "--out", str(tmp_path / "run"), "--quiet"])
    assert result.exit_code == 0, result.output
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    scores = metrics["controllers"]["none"]
    assert {"nsl2", "shift_x_m"} <= set(scores) and not any("pitch" in name for name in scores)
    assert any(note.startswith("trace_pitch_left_m") and "no complete period" in note for note in metrics["notes"])
    assert "note: trace_pitch_left_m" in result.output
