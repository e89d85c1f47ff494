"""Fuzzed bad scenarios (issue 6): every malformed scenario file makes ``afmsim validate`` and
``afmsim run`` exit with code 2 and one ``error:`` line naming the field, print no traceback and
leave no output folder (nor a hidden staging folder) behind.

The corpus is a systematic mutation of ``scenarios/quick.yaml`` with every default filled in
(wrong types, unknown and missing keys at every level, zero/negative/NaN/inf/huge numbers, units
in strings, lists of the wrong length, impossible combinations, scenarios too big for memory),
plus broken files (YAML syntax, encodings, binary, sizes, paths) and hypothesis-generated
mappings. Most cases run in-process with typer's CliRunner; a few in real processes.
"""

import copy
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import typer
import typer.testing
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from afmsim.cli import app
from afmsim.scenario import MAX_DEPTH, MAX_FILE_BYTES, load_scenario

ROOT = Path(__file__).resolve().parents[1]
QUICK = ROOT / "scenarios" / "quick.yaml"
FULL = load_scenario(QUICK).model_dump(mode="json")     # every field, defaults included
runner = CliRunner()


@pytest.fixture(scope="module", autouse=True)
def _cli_built_once():
    """typer rebuilds the click command from the function signatures on every invoke (≈ 5 ms, more
    than a refused scenario costs); build it once for this module's ~1300 invocations."""
    command = typer.main.get_command(app)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(typer.testing, "_get_command", lambda _app: command)
        yield


# ------------------------------------------------------------------------------- corpus
def _leaves(tree, prefix=()):
    """(path, value) of every scalar and list in the scenario mapping."""
    for key, value in tree.items():
        path = (*prefix, key)
        if isinstance(value, dict):
            yield from _leaves(value, path)
        else:
            yield path, value


def _blocks(tree, prefix=()):
    for key, value in tree.items():
        if isinstance(value, dict):
            yield (*prefix, key)
            yield from _blocks(value, (*prefix, key))


def _set(tree, path, value):
    data = copy.deepcopy(tree)
    node = data
    for key in path[:-1]:
        node = node[key]
    if isinstance(node, list):
        node[int(path[-1])] = value
    else:
        node[path[-1]] = value
    return data


def _drop(tree, path):
    data = copy.deepcopy(tree)
    node = data
    for key in path[:-1]:
        node = node[key]
    del node[path[-1]]
    return data


def _dotted(path):
    return ".".join(str(p) for p in path)


BAD_NUMBERS = [("negative", -1), ("nan", math.nan), ("inf", math.inf), ("minus-inf", -math.inf), ("huge", 1e300),
               ("true", True), ("false", False), ("unit-um", "30 um"), ("unit-m", "3e-5 m"), ("empty-string", ""),
               ("null", None), ("list", [1.0, 2.0]), ("mapping", {"value": 1.0})]
ZERO_IS_VALID = {"seed", "z_feedback.kp", "z_feedback.deflection_noise_nm", "stage.cross_coupling",
                 "scan.offset_um.0", "scan.offset_um.1"}
BAD_BOOLS = [("int", 1), ("string", "yes"), ("float", 0.5), ("null", None), ("list", [True])]
BAD_CHOICES = [("unknown", "bogus"), ("int", 3), ("null", None), ("list", ["x"]), ("empty", "")]
BAD_NAMES = [("int", 5), ("slash", "../escape"), ("space", "my run"), ("long", "a" * 65), ("newline", "a\nb"),
             ("empty", ""), ("null", None), ("list", ["quick"])]
BAD_PAIRS = [("one", [30.0]), ("three", [1.0, 2.0, 3.0]), ("empty", []), ("scalar", 30.0), ("string", "30 30"),
             ("mapping", {"x": 30.0})]
BAD_CONTROLLERS = [("string", "none"), ("empty", []), ("unknown", ["magic"]), ("int", [1]), ("nested", [["none"]]),
                   ("null", None)]
BAD_BLOCKS = [("list", [1]), ("string", "x"), ("int", 7), ("null", None)]


def _mutations():
    """(id, scenario mapping, text naming the field) for every field of the full quick scenario."""
    for path, value in _leaves(FULL):
        where = _dotted(path)
        if value is None:  # an optional file reference left unset (instrument): tested where it is read
            continue
        if path == ("name",):
            bad = BAD_NAMES
        elif isinstance(value, bool):
            bad = BAD_BOOLS
        elif isinstance(value, (int, float)):
            bad = BAD_NUMBERS + ([] if where in ZERO_IS_VALID else [("zero", 0)])
        elif isinstance(value, str):
            bad = BAD_CHOICES
        elif path == ("controllers",):
            bad = BAD_CONTROLLERS
        else:  # the (x, y) pairs: the pair itself and each element
            bad = BAD_PAIRS
            for index in range(len(value)):
                for label, item in BAD_NUMBERS + ([] if f"{where}.{index}" in ZERO_IS_VALID else [("zero", 0)]):
                    yield f"{where}.{index}={label}", _set(FULL, (*path, index), item), f"{where}.{index}"
        for label, item in bad:
            yield f"{where}={label}", _set(FULL, path, item), where
    for path in _blocks(FULL):
        where = _dotted(path)
        for label, item in BAD_BLOCKS:
            yield f"{where}={label}", _set(FULL, path, item), where
        yield f"{where}+unknown", _set(FULL, (*path, "bogus_key"), 1), f"{where}.bogus_key"
    yield "top+unknown", {**FULL, "colour": "blue"}, "colour"
    yield "top+non-string-key", {**FULL, 1: 2}, "Keys should be strings"
    yield "missing-sample", _drop(FULL, ("sample",)), "sample"
    yield "missing-sample.kind", _drop(FULL, ("sample", "kind")), "sample.kind"
    yield "sample.kind=grating-with-lens-fields", _set(FULL, ("sample", "kind"), "grating"), "sample."


def _scenario(**blocks):
    data = copy.deepcopy(FULL)
    for key, value in blocks.items():
        data[key] = {**data[key], **value} if isinstance(value, dict) and key != "sample" else value
    return data


TMP = "{tmp}"   # replaced by the case's temporary folder


def _combinations():
    """Valid fields, impossible together; missing sample files; scenarios too big for memory."""
    capi = {"controllers": ["none", "capi"], "identification": {"n_operators": 50}}
    return [
        ("lens-sag-over-radius", _scenario(sample={"kind": "microlens", "diameter_um": 2, "sag_um": 1.5}),
         "sample.sag_um"),
        ("lens-pitch-under-diameter", _scenario(sample={"kind": "microlens", "diameter_um": 10, "pitch_um": 5}),
         "sample.pitch_um"),
        ("grating-shallow-sidewalls", _scenario(sample={"kind": "grating", "step_nm": 5000, "sidewall_deg": 30}),
         "sample.sidewall_deg"),
        ("z-loop-unstable", _scenario(z_feedback={"ki_per_s": 50000}, numerics={"z_loop_rate_hz": 1000}),
         "z_feedback.ki_per_s"),
        ("capi-one-operator", _scenario(controllers=["capi"], identification={"n_operators": 1}),
         "identification.n_operators"),
        ("identification-too-few-samples", _scenario(identification={"sample_rate_hz": 10, "frequency_hz": 100}),
         "identification.sample_rate_hz"),
        ("mesh-missing-file", _scenario(sample={"kind": "mesh", "path": f"{TMP}/absent.stl"}), "sample.path"),
        ("mesh-path-is-folder", _scenario(sample={"kind": "mesh", "path": f"{TMP}/folder.stl"}), "sample.path"),
        ("mesh-wrong-suffix", _scenario(sample={"kind": "mesh", "path": "lens.docx"}), "sample.path"),
        ("heightmap-missing-file", _scenario(sample={"kind": "heightmap", "path": "absent.npy", "pixel_size_nm": 50}),
         "sample.path"),
        ("heightmap-no-pixel-size", _scenario(sample={"kind": "heightmap", "path": "absent.npy"}),
         "sample.pixel_size_nm"),
        ("memory-2048px-spp64", _scenario(scan={"pixels": 2048, "lines": 2048}, numerics={"samples_per_pixel": 64},
                                          **capi), "needs ≈"),
        ("memory-approach", _scenario(scan={"pixels": 2048, "line_rate_hz": 100},
                                      numerics={"samples_per_pixel": 64, "approach_s": 100}, **capi), "needs ≈"),
        ("field-beyond-travel-x", _scenario(scan={"offset_um": [95, 2], "size_um": [20, 20]}),
         "scan.offset_um[0] + scan.size_um[0] = 95 + 20 = 115 µm exceeds the stage travel 100 µm (x)"),
        ("field-beyond-travel-y", _scenario(scan={"offset_um": [2, 80.5], "size_um": [20, 20]}),
         "scan.offset_um[1] + scan.size_um[1] = 80.5 + 20 = 100.5 µm exceeds the stage travel 100 µm (y)"),
        ("size-with-unit", _scenario(scan={"size_um": "30 um"}), "scan.size_um: expected [x, y] in µm, got '30 um'"),
        ("misspelt-field", _scenario(scan={"line_rate": 2}), "scan.line_rate: unknown field; did you mean 'line_rate_hz'?"),
        ("memory-sample-grid", _scenario(scan={"size_um": [100, 0.1], "offset_um": [0, 0], "lines": 2048},
                                         numerics={"sample_oversampling": 8}), "needs ≈"),
        ("memory-lens-pitch", _scenario(sample={"kind": "microlens", "diameter_um": 0.5, "sag_um": 0.1,
                                                "pitch_um": 0.5}, scan={"size_um": [100, 100], "offset_um": [0, 0]}),
         "sample.pitch_um: needs ≈"),
    ]


RAW_FILES = [
    ("yaml-unclosed-list", "scan: [unclosed\n", "line 2"),
    ("yaml-unclosed-brace", "sample: {kind: microlens\n", "not valid YAML"),
    ("yaml-unclosed-quote", "name: 'unterminated\n", "not valid YAML"),
    ("yaml-bad-indent", "sample:\n  kind: microlens\n   diameter_um: 3\n", "not valid YAML"),
    ("yaml-tab-indent", "sample:\n\tkind: microlens\n", "not valid YAML"),
    ("yaml-double-colon", "name: a: b\n", "not valid YAML"),
    ("yaml-garbage-brackets", "{]\n", "not valid YAML"),
    ("yaml-list-then-key", "- a\nb: c\n", "not valid YAML"),
    ("yaml-duplicate-key", "name: a\nname: b\nsample: {kind: microlens}\n", "duplicate key 'name'"),
    ("yaml-duplicate-nested", "sample: {kind: microlens, kind: grating}\n", "duplicate key 'kind'"),
    ("yaml-two-documents", "name: a\n---\nname: b\n", "not valid YAML"),
    ("yaml-python-tag", "name: !!python/object/apply:os.system ['true']\n", "not valid YAML"),
    ("yaml-alias", "scan: &s {pixels: 64}\nsample: {kind: microlens}\nz: *s\n", "alias *s not allowed"),
    ("yaml-anchor-bomb", "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(     # "billion laughs": 9⁹ items
        f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join([f'*{chr(97 + i)}'] * 9)}]\n" for i in range(8)),
     "alias *a not allowed"),
    ("yaml-self-alias", "a: &a [*a]\n", "not valid YAML"),
    ("yaml-deep-nesting", "name: " + "[" * (MAX_DEPTH + 5) + "]" * (MAX_DEPTH + 5) + "\n", "nested deeper"),
    ("yaml-control-char", "name: a\x07b\n", "not valid YAML"),
    ("yaml-nul-char", "name: a\x00b\n", "not valid YAML"),
    ("empty-file", "", "scenario: empty"),
    ("whitespace-only", "   \n\n", "scenario: empty"),
    ("comment-only", "# nothing here\n", "scenario: empty"),
    ("yaml-list", "- name: quick\n- sample: {kind: microlens}\n", "scenario: must be a mapping"),
    ("yaml-scalar", "42\n", "scenario: must be a mapping"),
    ("yaml-string", "hello world\n", "scenario: must be a mapping"),
    ("yaml-null-key", "~: 1\nsample: {kind: microlens}\n", "Keys should be strings"),
    ("yaml-date-name", "name: 2024-01-01\nsample: {kind: microlens}\n", "name"),
    ("yaml-1e5-is-number", "sample: {kind: microlens}\nidentification: {sample_rate_hz: 1e9}\n",
     "identification.sample_rate_hz: must be in"),
]
BINARY_FILES = [
    ("binary-all-bytes", bytes(range(256)), "not UTF-8"),
    ("binary-random", b"\xff" + np.random.default_rng(6).integers(0, 256, 4096, dtype=np.uint8).tobytes(), "not UTF-8"),
    ("latin-1", "name: café\nsample: {kind: microlens}\n".encode("latin-1"), "not UTF-8"),
    ("utf-16", "name: quick\n".encode("utf-16"), "not UTF-8"),
    ("too-large", b"# padding\n" * (MAX_FILE_BYTES // 10 + 1), "larger than"),
]


def _write_case(tmp_path: Path, case) -> Path:
    kind, payload = case
    if kind == "mapping":
        path = tmp_path / "scenario.yaml"
        text = yaml.safe_dump(payload, allow_unicode=True)
        if f"{TMP}/folder.stl" in text:
            (tmp_path / "folder.stl").mkdir()
        path.write_text(text.replace(TMP, str(tmp_path)))
    elif kind == "text":
        path = tmp_path / "scenario.yaml"
        path.write_bytes(payload.encode("utf-8"))
    elif kind == "bytes":
        path = tmp_path / "scenario.yaml"
        path.write_bytes(payload)
    elif kind == "folder":
        path = tmp_path / "folder.yaml"
        path.mkdir()
    else:
        path = tmp_path / payload
    return path


def _corpus():
    """Every case as (id, (kind, payload), expected text in the error line); built without files."""
    cases = [(name, ("mapping", data), where) for name, data, where in [*_mutations(), *_combinations()]]
    cases += [(name, ("text", text), where) for name, text, where in RAW_FILES]
    cases += [(name, ("bytes", data), where) for name, data, where in BINARY_FILES]
    cases += [("directory", ("folder", None), "cannot read"),
              ("missing-file", ("missing", "absent.yaml"), "cannot read"),
              ("missing-file-newline-name", ("missing", "bad\nname.yaml"), "cannot read")]
    return cases


CORPUS = _corpus()


def test_the_corpus_is_large_and_its_cases_distinct():
    ids = [name for name, _, _ in CORPUS]
    assert len(ids) == len(set(ids))
    assert len(ids) >= 200, len(ids)


def _assert_refused(result, expected: str):
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    assert isinstance(result.exception, SystemExit)
    assert "Traceback" not in result.output
    assert result.stdout == ""
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert expected in lines[0], lines[0]


def _assert_nothing_written(tmp_path: Path, inputs) -> None:
    assert not (tmp_path / "o").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(inputs)   # no staging folder either


@pytest.mark.parametrize("name, case, expected", CORPUS, ids=[c[0] for c in CORPUS])
def test_bad_scenario_is_refused_with_one_line_and_nothing_written(tmp_path, name, case, expected):
    path = _write_case(tmp_path, case)
    inputs = [p.name for p in tmp_path.iterdir()]
    for command in (["validate", str(path)], ["run", str(path), "--out", str(tmp_path / "o"), "--quiet"]):
        _assert_refused(runner.invoke(app, command), expected)
    _assert_nothing_written(tmp_path, inputs)


def test_real_processes_print_no_traceback(tmp_path):
    """A few cases through ``python3 -m afmsim`` (encoding, memory guard, YAML syntax), started together."""
    cases = {
        "latin1.yaml": ("bytes", "name: café\n".encode("latin-1"), "run", "not UTF-8"),
        "bomb.yaml": ("mapping", _scenario(scan={"pixels": 2048, "lines": 2048}, numerics={"samples_per_pixel": 64},
                                           controllers=["none", "capi"], identification={"n_operators": 50}),
                      "run", "needs ≈"),
        "broken.yaml": ("text", "scan: [unclosed\n", "validate", "not valid YAML"),
    }
    procs = {}
    for file_name, (kind, payload, command, _) in cases.items():
        folder = tmp_path / file_name.removesuffix(".yaml")
        folder.mkdir()
        path = folder / file_name
        path.write_bytes(payload if kind == "bytes" else
                         (yaml.safe_dump(payload) if kind == "mapping" else payload).encode())
        args = [sys.executable, "-m", "afmsim", command, str(path)]
        args += ["--out", str(folder / "o"), "--quiet"] if command == "run" else []
        procs[file_name] = (folder, subprocess.Popen(args, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                                     text=True))
    for file_name, (folder, proc) in procs.items():
        stdout, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 2, (file_name, stderr)
        assert "Traceback" not in stdout + stderr
        assert len(stderr.splitlines()) == 1 and stderr.startswith("error: ") and cases[file_name][3] in stderr, stderr
        assert [p.name for p in folder.iterdir()] == [file_name]


# ------------------------------------------------------------------------------- hypothesis
_scalars = st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats(allow_nan=True) | st.text(max_size=12)
_values = st.recursive(_scalars, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                                             max_size=4), max_leaves=12)
_keys = st.sampled_from([*FULL, "sample", "kind", "bogus"]) | st.text(max_size=10)
_LEAF_PATHS = [path for path, _ in _leaves(FULL)]
_FUZZ = settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


def _check_any_outcome(text_or_bytes) -> None:
    """Valid (exit 0) or refused cleanly; a refused scenario is refused by ``run`` too, writing nothing."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        path = tmp / "fuzz.yaml"
        raw = text_or_bytes if isinstance(text_or_bytes, bytes) else text_or_bytes.encode("utf-8", "replace")
        path.write_bytes(raw)
        result = runner.invoke(app, ["validate", str(path)])
        assert result.exit_code in (0, 2), (result.output, result.exception)
        assert "Traceback" not in result.output
        if result.exit_code == 2:
            assert len(result.stderr.splitlines()) == 1 and result.stderr.startswith("error: "), result.stderr
            ran = runner.invoke(app, ["run", str(path), "--out", str(tmp / "o"), "--quiet"])
            assert ran.exit_code == 2 and ran.stderr == result.stderr
            assert [p.name for p in tmp.iterdir()] == ["fuzz.yaml"]


@_FUZZ
@given(st.dictionaries(_keys, _values, max_size=6))
def test_random_mappings_are_valid_or_refused_cleanly(data):
    _check_any_outcome(yaml.safe_dump(data, allow_unicode=True))


@_FUZZ
@given(st.sampled_from(_LEAF_PATHS), _values)
def test_random_values_in_the_quick_scenario_are_valid_or_refused_cleanly(path, value):
    _check_any_outcome(yaml.safe_dump(_set(FULL, path, value), allow_unicode=True))


@_FUZZ
@given(st.text(max_size=200) | st.binary(max_size=200))
def test_random_files_are_valid_or_refused_cleanly(content):
    _check_any_outcome(content)
