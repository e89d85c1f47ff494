"""Sim-to-real gap diagnosis: input validation, report structure, a small validation run, real record."""

import json
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from afmsim.diagnosis import diagnose_loops, load_record, validate_diagnosis
from afmsim.diagnosis.plausible import implausible
from afmsim.diagnosis.loops.validation import _dynamics, _plant, case_plan, excitation, make_case

SHARED = Path(__file__).resolve().parents[2] / "shared"
RECORD = SHARED / "real-data" / "piezo-sine-150V-1Hz.csv"


def _arrays(n=3000, fs=1000.0):
    t = np.arange(n) / fs
    v = 5 + 4 * np.sin(2 * np.pi * 1.0 * t)
    return t, v, 1e-5 * v


def test_bad_inputs_raise_one_line(tmp_path):
    t, v, x = _arrays()
    p = tmp_path / "bad.csv"
    p.write_text("t_s,v_V\n0,1\n")
    with pytest.raises(ValueError, match="lacks column"):
        load_record(p)
    with pytest.raises(ValueError, match="too short"):
        load_record((t[:50], v[:50], x[:50]))
    t2 = t.copy()
    t2[100] = t2[99]
    with pytest.raises(ValueError, match="not strictly increasing"):
        load_record((t2, v, x))
    x2 = x.copy()
    x2[200:205] = np.nan
    with pytest.raises(ValueError, match="run of NaN"):
        load_record((t, v, x2))
    with pytest.raises(ValueError, match="constant"):
        load_record((t, np.ones_like(v), x))
    for exc in (pytest.raises(ValueError),):
        with exc as info:
            load_record({"t_s": t, "x_m": x})
        assert "\n" not in str(info.value)


def test_single_nan_interpolated_and_long_record_decimated():
    t, v, x = _arrays(n=20000, fs=2000.0)
    x = x.copy()
    x[500] = np.nan
    rec = load_record((t, v, x))
    assert rec.decimation == 3 and np.all(np.isfinite(rec.x)) and rec.n <= 8000


def test_report_structure_and_figure(tmp_path):
    case = make_case(("drift", 2), np.random.default_rng(3))
    rep, summary = diagnose_loops(case["columns"], figure_path=tmp_path / "d.png")
    json.dumps(rep)  # serialisable
    assert rep["baseline"]["unit"] == "m" and rep["baseline"]["rms_gap"] > 0
    assert {"time", "motion", "branch", "position", "rate", "frequency"} <= set(rep["where"])
    names = {e["name"] for e in rep["effects"]}
    assert {"creep", "drift", "dynamics"} <= names
    for e in rep["effects"]:
        assert {"name", "params", "heldout_shrink", "significant"} <= set(e)
    assert rep["verdict"] and rep["verdict"][0] == "drift"
    assert rep["status"] in ("explained", "partly_explained", "unexplained")
    for key in ("baseline", "final", "unexplained"):
        assert rep[key]["gap_to_noise"] == pytest.approx(rep[key]["rms_gap"] / rep["baseline"]["noise_floor"], rel=1e-3)
    assert "Verdict" in summary and (tmp_path / "d.png").stat().st_size > 1000
    assert summary.splitlines()[-1] == "Minor-loop law: " + rep["minor_loop_law"]["note"]


@pytest.mark.parametrize("fs, f_amp", [(2000.0, 60.0), (1000.0, 25.0)])
def test_dynamics_lag_is_the_plants_low_frequency_delay(fs, f_amp):
    """A sine-driven record through amplifier pole × a resonance of ζ 0.15 at 2.5× the pole (bilinear,
    another code path than the candidate): ``dynamics`` passes the test with a delay of
    1/ω_a + 2ζ/ω_0 within 15 %, and no ringing — the drive stays far below the mode, so the mode is
    at most seen by its inertia, near its true f0 — which a rate-dependent loop width mimics to first
    order; here the width's play columns fit the training part worse, so the term is named (the
    25 Hz pole's 6.4 ms beyond the plausible 5 ms, and its 62.5 Hz mode below the plausible 100 Hz:
    reported as implausible), and no other candidate takes its shrink (creep took it at an
    implausible 0.08–0.19 %/decade once; run again without the implausible lag, a creep that
    relaxes within 0.1 s passes and is reported, not named)."""
    rng = np.random.default_rng(17)
    t, v = excitation("sines", fs, 10.0, rng)
    axis = _plant()
    b, a, true_lag = _dynamics(fs, f_amp)
    x = lfilter(b, a, axis.static_displacement(axis.drive(t, v))) + 10e-9 * rng.standard_normal(t.size)
    rep, summary = diagnose_loops({"t_s": t, "v_V": v, "x_m": x})
    dyn = {e["name"]: e for e in rep["effects"]}["dynamics"]
    assert dyn["params"]["lag_time_constant_s"] == pytest.approx(true_lag, rel=0.15)
    if "resonance_hz" in dyn["params"]:
        assert dyn["params"]["resonance_seen"] == "inertia"
        assert dyn["params"]["resonance_hz"] == pytest.approx(min(2.5 * f_amp, 0.3 * fs), rel=0.25)
    assert "alike_outside" not in dyn and dyn["heldout_shrink"] > 0.9, summary
    assert rep["verdict"] == ["dynamics"] and not [c for c in rep["caveats"] if not c.get("without_implausible")], summary
    if true_lag <= 5e-3:   # 60 Hz pole: a finding, which takes the gap
        assert rep["unexplained"]["share_left"] < 0.1 and not rep["implausible"], summary
    else:                  # 25 Hz pole: beyond the plausible lag (5 ms), reported as such, not a finding
        assert {f["effect"] for f in rep["implausible"]} == {"dynamics"} and rep["status"] == "unexplained", summary


def test_symmetric_baseline_offers_asymmetry():
    case = make_case(("null", 0), np.random.default_rng(5))
    rep, _ = diagnose_loops(case["columns"], baseline="symmetric")
    assert "asymmetry" in {e["name"] for e in rep["effects"]}
    eff = {e["name"]: e for e in rep["effects"]}
    # the plant is asymmetric Preisach: asymmetry is the candidate that shrinks the gap most
    # (known limitation: with 14 extra terms it does not always pass the ΔBIC test)
    assert eff["asymmetry"]["heldout_shrink"] == max(e["heldout_shrink"] for e in rep["effects"])
    assert eff["asymmetry"]["heldout_shrink"] > 0.2


def test_small_validation_run():
    scores = validate_diagnosis(n_cases=8, seed=0)
    assert scores["n_cases"] == 8 and scores["null_cases"] >= 2
    assert scores["top1_accuracy"] >= 0.75
    assert scores["false_alarm_rate"] <= 0.1
    assert len(case_plan(30)) == 30


def test_validation_cases_are_the_same_on_one_and_two_workers(monkeypatch):
    """Each case's seed is drawn in plan order before any case runs, and the results come back in
    plan order: the cases (and so the scores) do not depend on the worker count. The diagnosis is
    replaced by a fingerprint of the simulated record, so the check costs no fits."""
    from afmsim.diagnosis.loops import validation

    def fingerprint(case):
        x = case["columns"]["x_m"]
        return {"effects": list(case["effects"]), "verdict": [], "status": "nothing_missing", "params": {},
                "top1": not case["effects"], "exact": not case["effects"],
                "record": [x.size, float(x.sum()), float(x[-1]), case["excitation"], case["fs"]]}

    monkeypatch.setattr(validation, "_score_case", fingerprint)
    serial = validate_diagnosis(n_cases=6, seed=5, workers=1)["cases"]
    parallel = validate_diagnosis(n_cases=6, seed=5, workers=2)["cases"]
    assert [c["record"] for c in parallel] == [c["record"] for c in serial]
    assert len({c["record"][1] for c in serial}) == 6  # six different records, not one repeated
    assert [c["effects"] for c in serial] == [list(make_case(spec, np.random.default_rng(0))["effects"])
                                              for spec in case_plan(6)]


def test_real_record():
    if not RECORD.is_file():
        pytest.skip(f"real record not available: {RECORD}")
    rep, summary = diagnose_loops(RECORD)
    assert rep["record"]["decimation"] > 1
    assert rep["baseline"]["rms_gap"] < 0.02 * rep["baseline"]["travel"]
    # the baseline's held-out gap is several times the noise floor: "nothing missing" would be false
    assert rep["baseline"]["gap_to_noise"] > 2.0 and rep["status"] != "nothing_missing"
    assert "nothing significant is missing" not in summary
    # a named effect is a finding only with a physical value (creep was once named at 11.6 %/decade)
    params = {e["name"]: e["params"] for e in rep["effects"]}
    assert all(implausible(c, params[c]) == [] for c in rep["findings"])
    flagged = {f["effect"] for f in rep["implausible"]}
    assert flagged <= set(rep["verdict"]) and not flagged & set(rep["findings"])
    if rep["status"] in ("partly_explained", "unexplained"):
        assert rep["unexplained"]["gap_to_noise"] > 2.0 and "time" in rep["unexplained"]["where"]
    # the 3.26 s at 0 V before the drive's first step measure the sensor's whole noise: coloured (more
    # than the white floor), yet the remainder at the drive's frequencies is well above it there
    rest = rep["baseline"]["rest_noise"]
    assert rest["duration_s"] == pytest.approx(3.257, abs=0.01) and rest["coloured"]
    band = rest["against"]["bands"]["excitation_band"]
    assert rest["against"]["gap_to_rest_noise"] > 1.0 and band["remainder_rms"] > 2.0 * band["rest_rms"]
    assert "Noise at rest: the sensor reads" in summary


def test_spreadsheet_exports_load_like_the_plain_csv(tmp_path):
    """Semicolons with a UTF-8 byte-order mark (spreadsheet export), tabs, white space: the same record;
    a binary file is one line."""
    t, v, x = _arrays()
    rows = np.column_stack([t, v, x])
    plain = tmp_path / "plain.csv"
    np.savetxt(plain, rows, delimiter=",", header="t_s,v_V,x_m", comments="", fmt="%.10g")
    reference = load_record(plain)
    for name, delimiter, encoding in (("excel.csv", ";", "utf-8-sig"), ("tabs.txt", "\t", "utf-8"),
                                      ("spaces.dat", "  ", "utf-8")):
        path = tmp_path / name
        lines = [delimiter.join(("t_s", "v_V", "x_m"))] + [delimiter.join(f"{a:.10g}" for a in r) for r in rows]
        path.write_text("\n".join(lines) + "\n", encoding=encoding)
        record = load_record(path)
        assert np.array_equal(record.x, reference.x) and np.array_equal(record.v, reference.v), name
    junk = tmp_path / "junk.jpk"
    junk.write_bytes(bytes(range(256)) * 8)
    with pytest.raises(ValueError) as info:
        load_record(junk)
    assert "\n" not in str(info.value) and "junk.jpk" in str(info.value)


def test_a_ragged_csv_is_refused_in_one_line_naming_the_row(tmp_path):
    """A row with a column missing or one too many (a cut-off export): one line naming the first such
    row by its line in the file (comment lines and the header counted) and how many more there are."""
    t, v, x = _arrays()
    rows = [f"{a:.10g},{b:.10g},{c:.10g}" for a, b, c in zip(t, v, x)]
    rows[5] = rows[5].rsplit(",", 1)[0]
    rows[9] += ",0"
    path = tmp_path / "cut.csv"
    path.write_text("\n".join(["# sensor 2 kHz", "t_s,v_V,x_m"] + rows) + "\n")
    with pytest.raises(ValueError) as info:
        load_record(path)
    message = str(info.value)
    assert "\n" not in message and "cut.csv" in message
    assert "line 8 has 2 columns where the first data row has 3 (and 1 more such rows)" in message


def test_instrument_exports_with_words_and_comment_lines_load(tmp_path):
    """Settings as comment lines before the header and quantities named in words ("Time (s)",
    "Drive voltage [V]", "Displacement in nm", "Position-Y (µm)"): the same SI record."""
    t, v, x = _arrays()
    reference = load_record((t, v, x, 0.01 * x))
    path = tmp_path / "export.txt"
    head = ["# Instrument: capacitive sensor, 2 kHz", "% exported 2026-11-28", "",
            "Time (s)\tDrive voltage [V]\tDisplacement in nm\tPosition-Y (µm)\tStatus"]
    rows = [f"{a:.12g}\t{b:.12g}\t{c * 1e9:.12g}\t{c * 1e4:.12g}\t1" for a, b, c in zip(t, v, x)]
    path.write_text("\n".join(head + rows) + "\n", encoding="utf-8")
    record = load_record(path)
    assert np.allclose(record.t, reference.t, rtol=1e-9) and np.allclose(record.v, reference.v, rtol=1e-9)
    assert np.allclose(record.x, reference.x, rtol=1e-9, atol=1e-18)
    assert np.allclose(record.y, reference.y, rtol=1e-9, atol=1e-18)
    unnamed = tmp_path / "unnamed.csv"
    unnamed.write_text("Time (s),Signal A (V),Signal B (nm)\n" + "\n".join(f"{a},{b},{c}" for a, b, c in zip(t, v, x)))
    with pytest.raises(ValueError, match=r"lacks column\(s\) \['v_V', 'x_m'\]") as info:
        load_record(unnamed)
    assert "\n" not in str(info.value)


def test_unit_labelled_headers_are_converted_to_si(tmp_path):
    """Headers in other units (µm, ms, mV; underscore or brackets) give the SI record; an extra column
    is ignored; a unit not understood, or a quantity given twice, is one line naming the column."""
    t, v, x = _arrays()
    reference = load_record((t, v, x))
    labelled = tmp_path / "labelled.csv"
    np.savetxt(labelled, np.column_stack([t * 1e3, v * 1e3, x * 1e6, x]), delimiter=",",
               header="t [ms],V (mV),x_µm,x_set_m", comments="", fmt="%.12g", encoding="utf-8")
    record = load_record(labelled)
    assert np.allclose(record.t, reference.t, rtol=1e-9) and np.allclose(record.v, reference.v, rtol=1e-9)
    assert np.allclose(record.x, reference.x, rtol=1e-9, atol=1e-18)
    for header, expected in (("t_s,v_V,x_pm", "'x_pm' (x in m, mm"), ("t_s,v_V,x_m,x_nm", "x is given twice")):
        path = tmp_path / "bad_units.csv"
        np.savetxt(path, np.column_stack([t, v, x] + [x] * (header.count(",") - 2)), delimiter=",",
                   header=header, comments="")
        with pytest.raises(ValueError, match=re.escape(expected)) as info:
            load_record(path)
        assert "\n" not in str(info.value)
