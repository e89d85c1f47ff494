"""The command line: scenarios validated up front, bad input → exit 2 and one line, atomic run folders."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from afmsim.cli import app
from afmsim.diagnosis import load_images
from afmsim.experiment import run_scenario
from afmsim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()


@pytest.mark.parametrize("name", sorted(p.stem for p in (ROOT / "scenarios").glob("*.yaml")))
def test_bundled_scenarios_validate(name):
    result = runner.invoke(app, ["validate", str(ROOT / "scenarios" / f"{name}.yaml")])
    assert result.exit_code == 0, result.output
    assert "valid" in result.output


def test_validate_recognises_a_sweep_file_and_checks_every_run(tmp_path):
    result = runner.invoke(app, ["validate", str(ROOT / "scenarios" / "sweep-scan-size.yaml")])
    assert result.exit_code == 0, result.output
    assert "valid (sweep of 7 runs varying scan.size_um on microlens-128" in result.output
    sweep = yaml.safe_load((ROOT / "scenarios" / "sweep-scan-size.yaml").read_text())
    sweep["grid"]["scan.size_um"].append([99.0, 99.0])       # from offset 2 µm: 101 µm, past the travel
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump(sweep))
    result = runner.invoke(app, ["validate", str(path)])
    assert result.exit_code == 2
    assert result.output.strip().splitlines() == [
        "error: grid.scan.size_um: run 8/8 (scan.size_um=[99.0, 99.0]) makes an invalid scenario: scan.offset_um[0] "
        "+ scan.size_um[0] = 2 + 99 = 101 µm exceeds the stage travel 100 µm (x): lower offset_um or size_um"]


def _help(*command):
    result = runner.invoke(app, [*command, "--help"], env={"COLUMNS": "250"})
    assert result.exit_code == 0, result.output
    return result.output


def test_help_lists_the_choices_and_shows_no_value_for_flags():
    from afmsim.stage import HYSTERESIS_MODELS
    from typer.main import get_command

    assert f"<{'|'.join(HYSTERESIS_MODELS)}|all>" in _help("identify") and "linear" in HYSTERESIS_MODELS
    assert "<loops|images>" in _help("validate-diagnosis")
    assert "<preisach|symmetric>" in _help("diagnose") and "<auto|scenario|trace>" in _help("diagnose")
    for name in get_command(app).commands:
        assert "<bool>" not in _help(name), name
    assert "<bool>" not in _help() and "Show this message and exit" in _help()
    (quiet,) = [line for line in _help("run").splitlines() if "--quiet" in line]
    assert "No progress bar" in quiet and "<" not in quiet                  # a flag takes no value


def test_a_choice_outside_the_list_exits_2():
    for command in (["identify", "--hysteresis", "maxwell"], ["validate-diagnosis", "--kind", "pictures"]):
        result = runner.invoke(app, command)
        assert result.exit_code == 2 and command[-1] in result.output


BAD = [
    ({"scan": {"pixels": 4}}, "scan.pixels: must be in [16, 2048]"),
    ({"scan": {"size_um": [500, 10]}}, "scan.size_um.0: must be in [0.1, 100] µm"),
    ({"sample": {"kind": "microlens", "diameter_um": -3}}, "sample.diameter_um: must be in [0.5, 50] µm"),
    ({"z_feedback": {"ki_per_s": "fast"}}, "z_feedback.ki_per_s"),
    ({"controllers": ["magic"]}, "controllers.0"),
    ({"colour": "blue"}, "colour: unknown field (known: name, seed, experiments, sample,"),
    ({"stage": {"hysteresis": "maxwell"}}, "stage.hysteresis"),
    ({"scan": {"size_um": "30 um"}}, "scan.size_um: expected [x, y] in µm, got '30 um'"),
    ({"scan": {"offset_um": [2]}}, "scan.offset_um: expected [x, y] in µm, got [2]"),
    ({"scan": {"sise_um": [30, 30]}}, "scan.sise_um: unknown field; did you mean 'size_um'?"),
    ({"scna": {"pixels": 32}}, "scna: unknown field; did you mean 'scan'?"),
    ({"controllers": ["none", "diapy"]}, "controllers.1: must be one of none, spi, diapi, iiapi, capi, vendor, "
                                         "ideal (got 'diapy'); did you mean 'diapi'?"),
    ({"scan": {"offset_um": [95, 95], "size_um": [20, 20]}},
     "scan.offset_um[0] + scan.size_um[0] = 95 + 20 = 115 µm exceeds the stage travel 100 µm (x)"),
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
        assert (out / f"figure_{name}.png").stat().st_size > 10_000
    assert "e_D" in metrics
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["seed"] == 7 and manifest["config"]["name"] == "quick"
    assert {"numpy", "scipy", "afmsim"} <= set(manifest["versions"])
    assert "commit" in manifest["git"]
    with np.load(out / "images.npz") as arrays:
        assert arrays["trace_none"].shape == (64, 64) and arrays["retrace_diapi"].shape == (64, 64)
        error = arrays["error_retrace_none"]  # the deflection images: deflection less setpoint (m)
        assert error.shape == (64, 64) and abs(np.median(error)) < 0.5e-9 and np.ptp(error) > 1e-9
    record = load_images(out / "images.npz")  # the diagnosis reads them beside the heights
    assert record.error_channel == "deflection error (m)" and np.array_equal(record.error_retrace, error)
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
            np.testing.assert_array_equal(arrays[f"error_trace_{name}"], images.error_trace)


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


def test_identify_all_laws_writes_one_table2_with_a_block_per_law(tmp_path):
    from afmsim.identification import HYSTERETIC_LAWS

    out = tmp_path / "identify-all"
    result = runner.invoke(app, ["identify", "--out", str(out), "--experiments", "2", "--hysteresis", "all"])
    assert result.exit_code == 0, result.output
    assert set(HYSTERETIC_LAWS) == {"preisach", "duhem"}
    for law in HYSTERETIC_LAWS:
        assert f"{law} plant" in result.output
        assert (out / law / "identify.json").is_file() and (out / law / "fig6_loops.png").is_file()
    data = json.loads((out / "identify.json").read_text())
    assert list(data["laws"]) == list(HYSTERETIC_LAWS)
    for law in HYSTERETIC_LAWS:
        own = json.loads((out / law / "identify.json").read_text())
        assert data["laws"][law]["settings"]["plant"] == law
        assert data["laws"][law]["models"]["diapi"]["rms_V"] == own["models"]["diapi"]["rms_V"]
    header = (out / "table2.csv").read_text().splitlines()[0].split(",")
    assert "preisach_rms_V_spi" in header and "duhem_max_V_diapi" in header


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


def test_validate_diagnosis_writes_a_run_folder_under_outputs(tmp_path, monkeypatch):
    # where the scores go, not the validation itself (tests/test_diagnosis.py; 4 real cases take 10-30 s):
    # the validation is replaced by a double that records its arguments
    import afmsim.diagnosis

    calls = []
    monkeypatch.setattr(afmsim.diagnosis, "validate_diagnosis",
                        lambda n_cases, seed, workers=None: calls.append((n_cases, seed, workers))
                        or {"n_cases": n_cases, "cases": []})
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["validate-diagnosis", "--cases", "4", "--seed", "3", "--workers", "1"])
    assert result.exit_code == 0, result.output
    assert calls == [(4, 3, 1)]
    (folder,) = (tmp_path / "outputs").iterdir()
    assert folder.name.startswith("validate-diagnosis-loops-") and f"wrote outputs/{folder.name}" in result.output
    assert sorted(p.name for p in folder.iterdir()) == ["diagnosis.json", "manifest.json"]
    assert json.loads((folder / "diagnosis.json").read_text()) == {"n_cases": 4, "cases": []}
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["command"] == "validate-diagnosis" and manifest["config"] == {"cases": 4, "seed": 3, "kind": "loops"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["outputs"]       # nothing in benchmarks/results
    result = runner.invoke(app, ["validate-diagnosis", "--cases", "4", "--out", str(folder)])
    assert result.exit_code == 2 and "already exists" in result.output and calls == [(4, 3, 1)]
    result = runner.invoke(app, ["validate-diagnosis", "--cases", "5", "--out", str(tmp_path / "mine")])
    assert result.exit_code == 0 and (tmp_path / "mine" / "diagnosis.json").is_file()    # an explicit --out
