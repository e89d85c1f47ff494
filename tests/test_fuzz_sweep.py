"""Malformed sweep files: every one exits the CLI with code 2, one ``error:`` line, no traceback, no folder."""

import subprocess
import sys

import pytest
import yaml
from typer.testing import CliRunner

from afmsim.cli import app

runner = CliRunner()

BASE = {"name": "tiny", "experiments": 1, "sample": {"kind": "microlens"},
        "scan": {"size_um": [10.0, 10.0], "offset_um": [2.0, 2.0], "pixels": 32, "lines": 32},
        "controllers": ["none", "spi"], "identification": {"range": "scan"}}


def _grid(grid):
    return {"name": "bad", "base": BASE, "grid": grid}


def _random(parameters, draws=4):
    return {"name": "bad", "base": BASE, "random": {"draws": draws, "parameters": parameters}}


NAN, INF = float("nan"), float("inf")

# (case id, sweep file content: raw text/bytes or a mapping written as YAML, text the error line must contain)
CASES = [
    # the file itself
    ("empty-file", "", "sweep: must be a mapping"),
    ("top-level-list", "- a\n- b\n", "sweep: must be a mapping"),
    ("top-level-string", "just words\n", "sweep: must be a mapping"),
    ("top-level-number", "42\n", "sweep: must be a mapping"),
    ("yaml-unclosed-bracket", "grid: [unclosed\n", "not valid YAML"),
    ("yaml-nested-colon", "base: a: b\n", "not valid YAML"),
    ("yaml-tab-indent", "grid:\n\t- x\n", "not valid YAML"),
    ("yaml-bad-anchor", "base: *nowhere\n", "not valid YAML"),
    ("not-utf8", b"\xff\xfe\x00base: \x81\n", "not UTF-8"),
    ("duplicate-key", "base: a.yaml\nbase: b.yaml\n", "duplicate key 'base'"),
    ("alias-bomb", "a: &a [x, x]\nb: &b [*a, *a]\nc: [*b, *b]\n", "alias"),
    ("nested-too-deep", "grid: " + "[" * 40 + "]" * 40 + "\n", "nested deeper"),
    ("file-over-1-MiB", "# " + "x" * (1 << 20) + "\n", "larger than 1 MiB"),
    # top-level keys
    ("missing-base", {"name": "x", "grid": {"scan.pixels": [32]}}, "base"),
    ("unknown-key", {**_grid({"scan.pixels": [32]}), "colour": "blue"}, "colour: unknown field (known: name, seed, base, grid, random)"),
    ("misspelt-key", {**_grid({"scan.pixels": [32]}), "seeds": 3}, "seeds: unknown field; did you mean 'seed'?"),
    ("misspelt-path", _grid({"scan.pixel": [32]}), "scan has no field 'pixel'; did you mean 'pixels'?"),
    ("field-beyond-travel", _grid({"scan.offset_um": [[2.0, 2.0], [95.0, 2.0]]}),
     "grid.scan.offset_um: run 2/2 (scan.offset_um=[95.0, 2.0]) makes an invalid scenario: "
     "scan.offset_um[0] + scan.size_um[0] = 95 + 10 = 105 µm exceeds the stage travel 100 µm (x)"),
    ("name-not-string", {**_grid({"scan.pixels": [32]}), "name": 5}, "name"),
    ("name-with-slash", {**_grid({"scan.pixels": [32]}), "name": "../evil"}, "name: must be 1–64"),
    ("name-empty", {**_grid({"scan.pixels": [32]}), "name": ""}, "name"),
    ("name-too-long", {**_grid({"scan.pixels": [32]}), "name": "n" * 100}, "name"),
    ("seed-negative", {**_grid({"scan.pixels": [32]}), "seed": -1}, "seed: must be in"),
    ("seed-string", {**_grid({"scan.pixels": [32]}), "seed": "abc"}, "seed"),
    ("seed-fraction", {**_grid({"scan.pixels": [32]}), "seed": 1.5}, "seed"),
    ("seed-huge", {**_grid({"scan.pixels": [32]}), "seed": 2**64}, "seed: must be in"),
    ("nothing-to-vary", {"name": "x", "base": BASE}, "nothing to vary"),
    # the base scenario
    ("base-number", {**_grid({"scan.pixels": [32]}), "base": 5}, "base: must be a scenario file path"),
    ("base-list", {**_grid({"scan.pixels": [32]}), "base": ["a"]}, "base: must be"),
    ("base-empty-path", {**_grid({"scan.pixels": [32]}), "base": "  "}, "base: must be"),
    ("base-file-missing", {**_grid({"scan.pixels": [32]}), "base": "missing.yaml"}, "cannot read"),
    ("base-file-is-folder", {**_grid({"scan.pixels": [32]}), "base": "."}, "cannot read"),
    ("base-file-broken-yaml", {**_grid({"scan.pixels": [32]}), "base": "broken_base.yaml"}, "not valid YAML"),
    ("base-inline-invalid", {**_grid({"scan.pixels": [32]}), "base": {**BASE, "scan": {"pixels": 4}}},
     "base: scan.pixels: must be in [16, 2048]"),
    ("base-inline-no-sample", {**_grid({"scan.pixels": [32]}), "base": {"name": "x"}}, "base: sample"),
    ("base-inline-unknown-key", {**_grid({"scan.pixels": [32]}), "base": {**BASE, "laser": 1}}, "base: laser"),
    # grid structure and paths
    ("grid-is-list", {"base": BASE, "grid": ["scan.pixels"]}, "grid"),
    ("grid-is-number", {"base": BASE, "grid": 3}, "grid"),
    ("grid-empty-values", _grid({"scan.pixels": []}), "grid.scan.pixels: List should have at least 1 item"),
    ("grid-scalar-values", _grid({"scan.pixels": 32}), "grid.scan.pixels"),
    ("grid-empty-mapping", {"base": BASE, "grid": {}}, "nothing to vary"),
    ("grid-int-key", {"base": BASE, "grid": {1: [2]}}, "grid"),
    ("path-unknown-leaf", _grid({"scan.pixel": [32]}), "grid.scan.pixel: scan has no field 'pixel'"),
    ("path-unknown-block", _grid({"scann.pixels": [32]}), "has no field 'scann'"),
    ("path-empty", _grid({"": [1]}), "has no field ''"),
    ("path-below-a-value", _grid({"scan.pixels.extra": [1]}), "scan.pixels is a value"),
    ("path-index-out-of-range", _grid({"scan.size_um.2": [5.0]}), "not an index 0–1"),
    ("path-index-not-a-number", _grid({"scan.size_um.x": [5.0]}), "not an index"),
    ("path-negative-index", _grid({"controllers.-1": ["spi"]}), "not an index"),
    ("path-with-newline", _grid({"scan\npixels": [32]}), "has no field"),
    ("path-trailing-dot", _grid({"scan.": [32]}), "has no field ''"),
    ("paths-overlap", _grid({"scan": [{"pixels": 32}], "scan.pixels": [32]}), "overlaps grid.scan"),
    ("grid-duplicate-values", _grid({"scan.pixels": [32, 32]}), "grid.scan.pixels: duplicate value 32"),
    # grid values that make the scenario invalid
    ("value-out-of-range", _grid({"scan.pixels": [32, 4]}), "grid.scan.pixels: run 2/2 (scan.pixels=4)"),
    ("value-wrong-type", _grid({"scan.pixels": ["many"]}), "scan.pixels"),
    ("value-nan", _grid({"scan.line_rate_hz": [NAN]}), "scan.line_rate_hz: must be in [0.01, 100] Hz"),
    ("value-inf", _grid({"scan.line_rate_hz": [INF]}), "scan.line_rate_hz: must be in"),
    ("value-minus-inf", _grid({"stage.cross_coupling": [-INF]}), "stage.cross_coupling: must be in"),
    ("size-not-a-pair", _grid({"scan.size_um": [5.0]}), "scan.size_um"),
    ("size-too-large", _grid({"scan.size_um": [[500.0, 500.0]]}), "scan.size_um.0: must be in [0.1, 100] µm"),
    ("controller-unknown", _grid({"controllers": [["none", "magic"]]}), "controllers.1"),
    ("controllers-empty", _grid({"controllers": [[]]}), "controllers"),
    ("bool-field-word", _grid({"stage.creep": ["maybe"]}), "stage.creep"),
    ("seed-path-negative", _grid({"seed": [-1]}), "grid.seed: run 1/1"),
    ("value-mapping-for-number", _grid({"scan.pixels": [{"a": 1}]}), "scan.pixels"),
    ("sample-kind-changed", _grid({"sample.kind": ["grating"]}), "grid.sample.kind"),
    ("sample-file-missing", _grid({"sample": [{"kind": "heightmap", "path": "absent.npy", "pixel_size_nm": 50}]}),
     "grid.sample: run 1/1"),
    ("tiny-lens-pitch-string", _grid({"sample.pitch_um": ["12 µm"]}), "sample.pitch_um"),
    # run counts
    ("huge-product", _grid({"scan.pixels": list(range(16, 2048)), "scan.lines": list(range(2, 200))}),
     "more than the limit of 100,000"),
    ("huge-grid-times-draws", {**_grid({"scan.pixels": list(range(16, 1016))}),
                               "random": {"draws": 1000, "parameters": {"scan.line_rate_hz": {"uniform": [0.5, 2]}}}},
     "more than the limit"),
    ("draws-over-cap", _random({"scan.line_rate_hz": {"uniform": [0.5, 2]}}, draws=10**6), "random.draws: must be in"),
    # random structure
    ("draws-zero", _random({"scan.line_rate_hz": {"uniform": [0.5, 2]}}, draws=0), "random.draws: must be in"),
    ("draws-negative", _random({"scan.line_rate_hz": {"uniform": [0.5, 2]}}, draws=-5), "random.draws"),
    ("draws-word", _random({"scan.line_rate_hz": {"uniform": [0.5, 2]}}, draws="ten"), "random.draws"),
    ("draws-fraction", _random({"scan.line_rate_hz": {"uniform": [0.5, 2]}}, draws=2.5), "random.draws"),
    ("draws-nan", _random({"scan.line_rate_hz": {"uniform": [0.5, 2]}}, draws=NAN), "random.draws"),
    ("random-no-parameters", {"base": BASE, "random": {"draws": 3}}, "random.parameters"),
    ("random-empty-parameters", _random({}), "random.parameters"),
    ("random-unknown-key", {"base": BASE, "random": {"draws": 3, "parameters": {"seed": {"integers": [0, 9]}},
                                                     "method": "sobol"}}, "random.method"),
    ("random-not-mapping", {"base": BASE, "random": 5}, "random"),
    ("dist-unknown", _random({"scan.line_rate_hz": {"normal": [0, 1]}}), "random.parameters.scan.line_rate_hz.normal"),
    ("dist-two-kinds", _random({"scan.line_rate_hz": {"uniform": [1, 2], "loguniform": [1, 2]}}), "exactly one"),
    ("dist-no-kind", _random({"scan.line_rate_hz": {}}), "exactly one"),
    ("dist-as-list", _random({"scan.line_rate_hz": [1, 2]}), "scan.line_rate_hz"),
    ("uniform-reversed", _random({"scan.line_rate_hz": {"uniform": [2, 1]}}), "needs lo < hi"),
    ("uniform-empty-interval", _random({"scan.line_rate_hz": {"uniform": [1, 1]}}), "needs lo < hi"),
    ("uniform-nan", _random({"scan.line_rate_hz": {"uniform": [NAN, 1]}}), "bounds must be finite"),
    ("uniform-inf", _random({"scan.line_rate_hz": {"uniform": [0, INF]}}), "bounds must be finite"),
    ("uniform-one-bound", _random({"scan.line_rate_hz": {"uniform": [1]}}), "uniform"),
    ("uniform-words", _random({"scan.line_rate_hz": {"uniform": ["a", "b"]}}), "uniform"),
    ("loguniform-zero", _random({"scan.line_rate_hz": {"loguniform": [0, 1]}}), "loguniform needs 0 < lo"),
    ("loguniform-negative", _random({"scan.line_rate_hz": {"loguniform": [-1, 1]}}), "loguniform needs 0 < lo"),
    ("integers-fraction", _random({"scan.pixels": {"integers": [16.5, 40]}}), "integers"),
    ("choice-empty", _random({"scan.pixels": {"choice": []}}), "choice"),
    ("choice-not-list", _random({"scan.pixels": {"choice": 5}}), "choice"),
    ("random-bad-path", _random({"scan.nope": {"uniform": [1, 2]}}), "random.parameters.scan.nope: scan has no field"),
    ("random-draw-out-of-range", _random({"scan.line_rate_hz": {"uniform": [200, 300]}}),
     "random.parameters.scan.line_rate_hz: run 1/4"),
    ("random-integers-below-range", _random({"scan.pixels": {"integers": [1, 8]}}), "scan.pixels: must be in [16, 2048]"),
    ("random-choice-bad-item", _random({"controllers": {"choice": [["none"], ["magic"]]}}, draws=50), "controllers.0"),
    ("path-in-grid-and-random", {**_grid({"scan.pixels": [32]}),
                                 "random": {"draws": 2, "parameters": {"scan.pixels": {"integers": [16, 64]}}}},
     "scan.pixels is in both grid and random"),
]


def _write(folder, content):
    (folder / "broken_base.yaml").write_text("scan: [unclosed\n")
    path = folder / "sweep.yaml"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content if isinstance(content, str) else yaml.safe_dump(content, allow_unicode=True))
    return path


def test_corpus_is_large_and_distinct():
    assert len(CASES) >= 60 and len({case for case, _, _ in CASES}) == len(CASES)


@pytest.mark.parametrize("case, content, message", CASES, ids=[case for case, _, _ in CASES])
def test_malformed_sweep_exits_2_with_one_line(tmp_path, case, content, message):
    path = _write(tmp_path, content)
    before = sorted(p.name for p in tmp_path.iterdir())
    result = runner.invoke(app, ["sweep", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], result.stderr
    assert result.stdout == "" and "Traceback" not in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == before                    # no output folder, nothing else


@pytest.mark.parametrize("case", ["yaml-unclosed-bracket", "value-nan", "huge-product"])
def test_malformed_sweep_in_a_subprocess_prints_no_traceback(tmp_path, case):
    _, content, message = next(c for c in CASES if c[0] == case)
    path = _write(tmp_path, content)
    before = sorted(p.name for p in tmp_path.iterdir())
    proc = subprocess.run([sys.executable, "-m", "afmsim", "sweep", str(path)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("error: ") and message in proc.stderr
    assert "Traceback" not in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before                    # not even outputs/


def test_missing_sweep_file_and_folder_argument(tmp_path):
    for path in (tmp_path / "absent.yaml", tmp_path):
        result = runner.invoke(app, ["sweep", str(path), "--out", str(tmp_path / "out")])
        assert result.exit_code == 2 and result.stderr.startswith("error: ") and "cannot read" in result.stderr
        assert len(result.stderr.splitlines()) == 1 and not (tmp_path / "out").exists()
