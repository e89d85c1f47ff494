"""Real instrument files in: every format's channels, directions, units, sizes and line times;
the height pair; ``afmsim inspect``; ``diagnose --measured`` on vendor files; bad files → one line, exit 2.

Fixture files are made in ``tmp_path`` by ``vendor_files`` (beside this file): ``.gwy`` with
``gwyfile``, ``.ibw`` with ``igorwriter``, Park ``.tiff`` and JPK ``.jpk`` with ``tifffile`` (maintained
writers); no maintained package writes Nanoscope or Nanonis files, so ``write_nanoscope`` and
``write_sxm`` build minimal binary ones from the formats' layouts. The real Nanosurf files come from
``../shared/real-data/afm`` (tests skip without it).
"""

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from afmsim.cli import app
from afmsim.diagnosis import load_images
import afmsim.readers as readers
from afmsim.readers import ReaderError, pick_height_pair, read_afm_file
from afmsim.readers.channels import quantity_of, split_direction, to_si

from vendor_files import write_gwy, write_ibw, write_jpk, write_nanoscope, write_park, write_sxm

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real-data" / "afm"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason="../shared/real-data/afm not present")
runner = CliRunner()

# From ../shared/real-data/afm/README.md: height channel, scan size (m), time/line (s; the header's
# ScanTime where newer software writes it), channels in the file (both directions).
README = {
    "circles.nid": ("Topography", 50e-6, 2.0, 4),
    "squares_holes.nid": ("Topography", 50e-6, 2.0, 4),
    "grid1.nid": ("Z-Axis", 3e-6, 0.7803, 6),
    "SBS-PMMA.nid": ("Z-Axis", 25e-6, 0.5, 8),
    "image.nid": ("Z-Axis", 7.40729e-6, 0.80325, 6),
    "test.nid": ("Z-Axis", 50e-6, 0.8, 8),
}


def _grating(lines=24, points=32, shift_px=1.5, seed=0):
    """A ridge grating traced left → right and right → left: the retrace lags by ``shift_px`` pixels."""
    rng = np.random.default_rng(seed)
    x = np.arange(points)
    profile = lambda s: 50e-9 * (np.sin(2 * np.pi * (x - s) / 8.0) > 0)  # noqa: E731
    trace = np.tile(profile(0.0), (lines, 1)) + rng.normal(0, 0.5e-9, (lines, points))
    retrace = np.tile(profile(shift_px), (lines, 1)) + rng.normal(0, 0.5e-9, (lines, points))
    return trace, retrace


# --- vendor-neutral rules ----------------------------------------------------------------------

@pytest.mark.parametrize("title, expected", [
    ("Z-Axis forward", ("Z-Axis", "forward")), ("HeightRetrace", ("Height", "retrace")),
    ("ZSensorTrace", ("ZSensor", "trace")), ("Topography [Bwd]", ("Topography", "backward")),
    ("trace none", ("none", "trace")), ("Phase", ("Phase", "")), ("Amplitude (Fwd)", ("Amplitude", "forward")),
])
def test_direction_is_split_from_the_title(title, expected):
    assert split_direction(title) == expected


@pytest.mark.parametrize("name, unit, quantity", [
    ("Topography", "m", "height"), ("Z-Axis Sensor", "m", "height"), ("Deflection", "m", "deflection"),
    ("Friction force", "V", "lateral"), ("Amplitude", "V", "amplitude"), ("Phase", "deg", "phase"),
    ("Tip current", "A", "current"), ("none", "m", "height"), ("User input 1", "V", "other"),
])
def test_quantity_from_name_and_unit(name, unit, quantity):
    assert quantity_of(name, unit) == quantity


def test_units_to_si():
    assert to_si("nm") == ("m", 1e-9) and to_si("~m") == ("m", 1e-6) and to_si("µm") == ("m", 1e-6)
    assert to_si("°") == ("deg", 1.0) and to_si("mV") == ("V", 1e-3) and to_si("pA") == ("A", 1e-12)
    assert to_si("furlong") == ("furlong", 1.0)


# --- the real Nanosurf files ---------------------------------------------------------------------

@needs_real
@pytest.mark.parametrize("name", sorted(README))
def test_real_nid_channels_sizes_units_and_line_time(name):
    height, size, line_time, count = README[name]
    afm = read_afm_file(REAL / name)
    assert afm.format == "nid" and len(afm.channels) == count
    assert sorted({c.direction for c in afm.channels}) == ["backward", "forward"]
    for c in afm.channels:
        assert c.shape == (256, 256) and c.size_m == pytest.approx((size, size))
        assert c.line_time_s == pytest.approx(line_time)
        assert c.data.dtype == np.float64 and np.isfinite(c.data).all()
    trace, retrace, picked = pick_height_pair(afm)
    assert (trace.name, trace.direction, retrace.direction) == (height, "forward", "backward")
    assert trace.unit == "m" and f"'{height}'" in picked and "\n" not in picked
    span = np.ptp(trace.data)  # heights in metres: tens of nm to a few µm on these samples
    assert 5e-8 < span < 2e-5, span
    phases = [c for c in afm.channels if c.quantity == "phase"]
    assert all(c.unit == "deg" for c in phases)


@needs_real
def test_real_nid_down_frame_is_reversed_to_scan_order_and_both_directions_run_left_to_right():
    from NSFopen.read import nid_read

    afm = read_afm_file(REAL / "SBS-PMMA.nid")  # Scan direction=Down, CurLine=0
    stored = nid_read(str(REAL / "SBS-PMMA.nid"), dataframe=False).data["Image"]["Forward"]["Z-Axis"]
    trace, retrace, _ = pick_height_pair(afm)
    assert afm.metadata["slow_scan"] == "down"
    np.testing.assert_allclose(trace.data, stored[::-1])
    up = read_afm_file(REAL / "image.nid")
    assert up.metadata["slow_scan"] == "up"
    t, r, _ = pick_height_pair(up)
    level = lambda a: a - np.median(a, axis=1, keepdims=True)  # noqa: E731
    as_stored = np.corrcoef(level(t.data).ravel(), level(r.data).ravel())[0, 1]
    mirrored = np.corrcoef(level(t.data).ravel(), level(r.data[:, ::-1]).ravel())[0, 1]
    assert as_stored > 0.9 > mirrored


@needs_real
def test_real_nid_channel_override_and_refusals():
    afm = read_afm_file(REAL / "SBS-PMMA.nid")
    trace, retrace, picked = pick_height_pair(afm, "z-axis sensor")
    assert trace.name == "Z-Axis Sensor" and "--channel" in picked
    with pytest.raises(ReaderError, match="not a height"):
        pick_height_pair(afm, "Friction force")
    with pytest.raises(ReaderError, match="no channel 'Height'"):
        pick_height_pair(afm, "Height")


@needs_real
def test_real_nid_loads_as_image_record():
    afm = read_afm_file(REAL / "circles.nid")
    assert afm.metadata["scan_rotation_deg"] == -45 and "rotated -45°" in pick_height_pair(afm)[2]
    record = load_images(REAL / "circles.nid")
    assert record.shape == (256, 256) and record.scan_size_m == pytest.approx((50e-6, 50e-6))
    assert record.line_rate_hz == pytest.approx(0.25)  # 1 / (2 · 2 s)
    assert "Topography forward/backward" in record.source and record.scan_offset_m is None


@needs_real
@pytest.mark.parametrize("change, message", [("half", "truncated"), ("10 bytes less", "truncated"),
                                             ("10 bytes more", "bytes more after")])
def test_cut_or_padded_real_nid_is_one_line(tmp_path, change, message):
    raw = (REAL / "circles.nid").read_bytes()
    changed = tmp_path / "circles.nid"
    changed.write_bytes({"half": raw[:len(raw) // 2], "10 bytes less": raw[:-10], "10 bytes more": raw + bytes(10)}[change])
    with pytest.raises(ReaderError, match=message) as info:
        read_afm_file(changed)
    assert "\n" not in str(info.value)


@needs_real
def test_inspect_json_schema_on_a_real_file():
    result = runner.invoke(app, ["inspect", str(REAL / "test.nid"), "--json"])
    assert result.exit_code == 0, result.output
    listing = json.loads(result.output)
    assert listing["format"] == "nid" and len(listing["channels"]) == 8
    for channel in listing["channels"]:
        assert {"name", "direction", "unit", "shape", "size_m", "line_time_s"} <= set(channel)
        assert channel["shape"] == [256, 256] and channel["size_m"] == pytest.approx([50e-6, 50e-6])
    assert {(c["name"], c["direction"]) for c in listing["channels"]} >= {("Z-Axis Sensor", "backward"),
                                                                         ("Phase", "forward")}
    assert listing["error_signal"] == "Amplitude"  # dynamic mode: the amplitude, not the phase
    text = runner.invoke(app, ["inspect", str(REAL / "test.nid")])
    assert text.exit_code == 0 and "Z-Axis Sensor" in text.output and "picked 'Z-Axis'" in text.output
    assert "Z loop's error signal: 'Amplitude'" in text.output


# --- formats made with maintained writers (or from the spec) ----------------------------------------

def test_gwy_vendor_titles_units_and_directions(tmp_path):
    z = np.arange(20 * 24, dtype=float).reshape(20, 24)
    path = write_gwy(tmp_path / "scan.gwy", [("Z-Axis forward", z, "nm", 2.0, "µm"), ("Z-Axis backward", z + 1, "nm", 2.0, "µm"),
                                              ("Phase forward", z, "deg", 2.0, "µm")])
    afm = read_afm_file(path)
    assert afm.format == "gwy" and [c.direction for c in afm.channels] == ["forward", "backward", "forward"]
    trace, retrace, _ = pick_height_pair(afm)
    assert trace.name == "Z-Axis" and trace.unit == "m" and trace.size_m == pytest.approx((2e-6, 2e-6))
    np.testing.assert_allclose(retrace.data, (z + 1) * 1e-9)
    assert afm.channels[2].quantity == "phase" and afm.channels[2].line_time_s is None
    kept = write_gwy(tmp_path / "kept.gwy", [("Height (Trace)", z, "m", 1e-6, "m")], meta={"Scan Rate": "2 Hz"})
    assert read_afm_file(kept).channels[0].line_time_s == pytest.approx(0.25)  # 1 / (2 · 2 Hz)


def test_gwy_one_direction_or_no_height_is_refused(tmp_path):
    z = np.ones((16, 16)) * np.arange(16)
    one = read_afm_file(write_gwy(tmp_path / "one.gwy", [("Height Trace", z, "m", 1e-6, "m")]))
    with pytest.raises(ReaderError, match="trace scan only"):
        pick_height_pair(one)
    none = read_afm_file(write_gwy(tmp_path / "amp.gwy", [("Amplitude forward", z, "V", 1e-6, "m"),
                                                           ("Amplitude backward", z, "V", 1e-6, "m")]))
    with pytest.raises(ReaderError, match="no height channel"):
        pick_height_pair(none)


def test_ibw_asylum_layers_note_and_scan_down(tmp_path):
    trace, retrace = _grating()
    note = {"FastScanSize": 3.2e-7, "SlowScanSize": 2.4e-7, "ScanRate": 2.5, "ScanDown": 1, "ImagingMode": "AC Mode",
            "ScanAngle": 90}
    path = write_ibw(tmp_path / "asylum.ibw", {"HeightTrace": trace, "HeightRetrace": retrace,
                                                "ZSensorTrace": trace, "ZSensorRetrace": retrace,
                                                "PhaseTrace": trace * 1e9}, note)
    afm = read_afm_file(path)
    assert afm.format == "ibw" and len(afm.channels) == 5
    assert [(c.name, c.direction) for c in afm.channels[:2]] == [("Height", "trace"), ("Height", "retrace")]
    t, r, picked = pick_height_pair(afm)
    assert t.name == "Height" and "ZSensor" in picked  # the Z drive first, the sensor named as an alternative
    assert t.size_m == pytest.approx((3.2e-7, 2.4e-7)) and t.line_time_s == pytest.approx(0.2)  # 1/(2·2.5 Hz)
    np.testing.assert_allclose(t.data, trace[::-1], rtol=1e-6)  # ScanDown: rows reversed to scan order
    assert afm.channels[4].quantity == "phase" and afm.channels[4].unit == "deg"
    assert afm.metadata["scan_rotation_deg"] == 90 and "rotated 90°" in picked


def test_an_asylum_frame_stopped_early_loads_its_scanned_lines(tmp_path):
    """A scan-down .ibw stopped after 18 of 24 lines: the lines never scanned hold zeros where the file
    stores them (the top rows, in scan order the last); load_images drops them and the scan height."""
    trace, retrace = _grating()
    stored_t, stored_r = trace.copy(), retrace.copy()
    stored_t[:6], stored_r[:6] = 0.0, 0.0  # stored bottom-up: a scan-down frame's last lines are the top rows
    note = {"FastScanSize": 3.2e-7, "SlowScanSize": 2.4e-7, "ScanRate": 2.5, "ScanDown": 1}
    path = write_ibw(tmp_path / "stopped.ibw", {"HeightTrace": stored_t, "HeightRetrace": stored_r}, note)
    record = load_images(path)
    assert record.shape == (18, 32) and record.unscanned_lines == 6
    assert record.scan_size_m[1] == pytest.approx(2.4e-7 * 18 / 24)
    np.testing.assert_allclose(record.trace, trace[::-1][:18], rtol=1e-6)
    from afmsim.twin.measured import load_measured_pair  # the twin reads the same lines

    pair = load_measured_pair(path)
    assert pair.trace.shape == (18, 32) and pair.scan.size_m[1] == pytest.approx(2.4e-7 * 18 / 24)


def test_nanoscope_scaling_directions_and_line_time(tmp_path):
    rng = np.random.default_rng(1)
    raw_t = rng.integers(-20000, 20000, (16, 20)).astype(np.int16)
    raw_r = rng.integers(-20000, 20000, (16, 20)).astype(np.int16)
    path = write_nanoscope(tmp_path / "scan.001", [("Height", "Trace", raw_t), ("Height", "Retrace", raw_r),
                                                    ("Amplitude", "Trace", raw_t)], rate_hz=2.0, frame="Down")
    afm = read_afm_file(path)
    assert afm.format == "nanoscope" and [c.direction for c in afm.channels] == ["trace", "retrace", "trace"]
    t, r, _ = pick_height_pair(afm)
    nm_per_lsb = 440.0 / 65536 * 20.0  # Z scale (V over 2^16 LSB) × Zsens (nm/V)
    np.testing.assert_allclose(r.data, raw_r[::-1] * nm_per_lsb * 1e-9)  # Frame direction Down: rows reversed
    assert t.unit == "m" and t.size_m == pytest.approx((5e-6, 5e-6 * 16 / 20))
    assert t.line_time_s == pytest.approx(0.25)  # Scan Rate 2 Hz = 2 trace+retrace lines per second
    raw = path.read_bytes()  # a layer whose Z scale pySPM cannot parse is skipped, the others are read
    cut = raw.rindex(b"\\@2:Z scale: V [Sens. Zsens]")
    bad = b"\\@2:Z scale: unreadable-scal"
    path.write_bytes(raw[:cut] + bad + raw[cut + len(bad):])
    afm = read_afm_file(path)
    assert [c.name for c in afm.channels] == ["Height", "Height"] and afm.metadata["skipped_layers"]
    np.testing.assert_array_equal(afm.channels[1].data, r.data)


def test_jpk_channels_directions_scaling_rows_and_line_time(tmp_path):
    rng = np.random.default_rng(4)
    raw = rng.integers(-2**20, 2**20, (10, 14))
    path = write_jpk(tmp_path / "scan.jpk", [("Height", False, raw, 1e-10, 2e-9), ("Height", True, raw[:, ::-1], 1e-10, 0.0),
                                              ("Height (measured)", False, raw + 7, 1e-10, 0.0),
                                              ("Height (measured)", True, raw - 7, 1e-10, 0.0)], rate_hz=2.0)
    afm = read_afm_file(path)
    assert afm.format == "jpk"
    assert [(c.name, c.direction) for c in afm.channels] == [
        ("Height", "trace"), ("Height", "retrace"), ("Height (measured)", "trace"), ("Height (measured)", "retrace")]
    np.testing.assert_allclose(afm.channels[0].data, raw * 1e-10 + 2e-9)  # row 0 = the first line stored (scanned)
    np.testing.assert_allclose(afm.channels[1].data, raw[:, ::-1] * 1e-10)
    c = afm.channels[0]
    assert c.unit == "m" and c.size_m == pytest.approx((5e-6, 4e-6)) and c.line_time_s == pytest.approx(0.25)
    trace, retrace, picked = pick_height_pair(afm)
    assert trace.name == "Height" and "Z drive/topography" in picked and "Height (measured)" in picked
    assert pick_height_pair(afm, "height (measured)")[0].data[0, 0] == pytest.approx((raw[0, 0] + 7) * 1e-10)


def test_park_scaling_direction_rows_and_line_time(tmp_path):
    rng = np.random.default_rng(3)
    raw = rng.integers(-20000, 20000, (12, 16)).astype("<i2")
    up = read_afm_file(write_park(tmp_path / "fwd.tiff", raw, gain=2e-3, rate_hz=0.5, size_um=(8.0, 6.0)))
    assert up.format == "park" and len(up.channels) == 1
    (c,) = up.channels
    assert (c.name, c.direction, c.quantity, c.unit) == ("Z Height", "forward", "height", "m")
    np.testing.assert_allclose(c.data, raw * 2e-3 * 1e-6)  # gain (µm per unit) · raw; bottom line first = scanned first
    assert c.size_m == pytest.approx((8e-6, 6e-6)) and c.line_time_s == pytest.approx(1.0)  # 0.5 Hz trace+retrace
    flt = rng.normal(0, 100, (12, 16)).astype("<f4")  # float data in nm, scale and offset as Gwyddion applies them
    down = read_afm_file(write_park(tmp_path / "bwd.tif", flt, forward=False, up=False, gain=1.5, scale=2.0,
                                     offset=3.0, unit="nm", rate_hz=2.0))
    (d,) = down.channels
    assert d.direction == "backward" and down.metadata["slow_scan"] == "down"
    np.testing.assert_allclose(d.data, (1.5 * (2.0 * flt.astype(float) + 3.0) * 1e-9)[::-1], rtol=1e-6)  # rows reversed
    assert d.line_time_s == pytest.approx(0.25)


def test_park_refusals_are_one_line(tmp_path):
    import tifffile

    plain = tmp_path / "photo.tiff"
    tifffile.imwrite(plain, np.zeros((8, 8), np.uint8))
    volts = write_park(tmp_path / "amplitude.tiff", np.zeros((8, 8), "<i2"), name="Amplitude", unit="V")
    for path, words in ((plain, "without Park Systems' PSIA tags"), (volts, "only length channels")):
        with pytest.raises(ReaderError, match=words) as info:
            read_afm_file(path)
        assert "\n" not in str(info.value)
    fwd = write_park(tmp_path / "fwd.tiff", np.zeros((8, 8), "<i2"))
    with pytest.raises(ReaderError, match="same file is given twice"):
        readers.read_afm_files(fwd, fwd)
    other = write_park(tmp_path / "other_bwd.tiff", np.ones((8, 8), "<i2"), forward=False, size_um=(20.0, 5.0))
    with pytest.raises(ReaderError, match=r"scan sizes differ: \['10', '5'\] vs \['20', '5'\] µm"):
        pick_height_pair(readers.read_afm_files(fwd, other))


def test_park_forward_and_backward_files_diagnose_as_one_pair(tmp_path):
    trace, retrace = _grating(lines=20, points=32)
    nm = 1e-3  # gain: µm per stored unit (1 nm)
    fwd = write_park(tmp_path / "grating_fwd.tiff", np.round(trace / 1e-9).astype("<i2"), gain=nm,
                      size_um=(3.2, 2.0), rate_hz=1.0)
    bwd = write_park(tmp_path / "grating_bwd.tiff", np.round(retrace / 1e-9).astype("<i2"), gain=nm,
                      forward=False, size_um=(3.2, 2.0), rate_hz=1.0)
    listing = json.loads(runner.invoke(app, ["inspect", str(fwd), "--json"]).output)
    assert listing["format"] == "park" and listing["channels"][0]["line_time_s"] == pytest.approx(0.5)
    alone = runner.invoke(app, ["diagnose", "--measured", str(fwd), "--out", str(tmp_path / "alone")])
    assert alone.exit_code == 2 and "forward scan only" in alone.output and alone.output.count("\n") == 1
    assert "give the other file too (--retrace)" in alone.output
    assert not (tmp_path / "alone").exists()
    out = tmp_path / "pair"
    result = runner.invoke(app, ["diagnose", "--measured", str(fwd), "--retrace", str(bwd), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert result.output.splitlines()[0].startswith("grating_fwd.tiff: picked 'Z Height' forward/backward")
    record = load_images(fwd, retrace=bwd)
    np.testing.assert_allclose(record.trace, np.round(trace / 1e-9) * 1e-9, atol=1e-15)
    np.testing.assert_allclose(record.retrace, np.round(retrace / 1e-9) * 1e-9, atol=1e-15)
    manifest = json.loads((out / "manifest.json").read_text())
    assert "grating_bwd.tiff" in json.dumps(manifest)
    csv = tmp_path / "loop.csv"
    csv.write_text("t_s,v_V,x_m\n0,0,0\n")
    wrong = runner.invoke(app, ["diagnose", "--measured", str(csv), "--retrace", str(bwd), "--out", str(tmp_path / "w")])
    assert wrong.exit_code == 2 and "--retrace goes with an image file" in wrong.output


def test_nanonis_sxm_channels_directions_rows_and_line_times(tmp_path):
    rng = np.random.default_rng(6)
    z, z_back, amp = (rng.normal(0, 1e-8, (6, 10)) for _ in range(3))
    for scan_dir, kind in (("up", "FLOAT MSBFIRST"), ("down", "FLOAT LSBFIRST")):
        path = write_sxm(tmp_path / f"scan_{scan_dir}.sxm", [("Z", "m", "both", [z, z_back]),
                                                           ("Amplitude", "V", "forward", [amp])],
                         range_m=(2e-6, 1.2e-6), scan_time_s=(0.25, 0.3), scan_dir=scan_dir, scanit_type=kind)
        afm = read_afm_file(path)
        assert afm.format == "nanonis" and afm.metadata["slow_scan"] == scan_dir
        assert [(c.name, c.direction, c.quantity, c.unit) for c in afm.channels] == [
            ("Z", "forward", "height", "m"), ("Z", "backward", "height", "m"), ("Amplitude", "forward", "amplitude", "V")]
        f32 = lambda a: a.astype(np.float32).astype(float)  # noqa: E731 - the file's precision
        np.testing.assert_array_equal(afm.channels[0].data, f32(z))  # rows as stored = as scanned, up or down
        np.testing.assert_array_equal(afm.channels[1].data, f32(z_back)[:, ::-1])  # stored right → left
        assert [c.line_time_s for c in afm.channels] == pytest.approx([0.25, 0.3, 0.25])  # each direction its own
        assert afm.channels[0].size_m == pytest.approx((2e-6, 1.2e-6))
    trace, retrace, picked = pick_height_pair(afm)
    assert picked.startswith("scan_down.sxm: picked 'Z' forward/backward") and retrace.direction == "backward"


def test_nanonis_sxm_refusals_are_one_line(tmp_path):
    good = write_sxm(tmp_path / "good.sxm", [("Z", "m", "both", [np.zeros((4, 5)), np.ones((4, 5))])]).read_bytes()
    cases = {"foreign.sxm": (b"P3\n5 4\n" + good[20:], "not a Nanonis scan file"),
             "no_end.sxm": (good[:good.index(b":SCANIT_END:")], "no :SCANIT_END:"),  # pySPM would read on forever
             "no_mark.sxm": (good[:good.index(b"\x1a\x04")], "no data marker"),
             "cut.sxm": (good[:-7], r"truncated Nanonis file \(\d+ bytes, its 2 images need \d+\)"),
             "double.sxm": (good.replace(b"FLOAT MSBFIRST", b"DOUBLE MSBFIRST"), "DOUBLE MSBFIRST.*only FLOAT")}
    for name, (content, words) in cases.items():
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(ReaderError, match=words) as info:
            read_afm_file(path)
        assert "\n" not in str(info.value) and str(info.value).startswith(name)
    out = tmp_path / "out"
    result = runner.invoke(app, ["diagnose", "--measured", str(tmp_path / "cut.sxm"), "--out", str(out)])
    assert result.exit_code == 2 and result.output.count("\n") == 1 and not out.exists()


def test_nanonis_sxm_pair_diagnoses_and_a_stopped_frame_keeps_its_scanned_lines(tmp_path):
    trace, retrace = _grating(lines=20, points=32)
    path = write_sxm(tmp_path / "grating.sxm", [("Z", "m", "both", [trace, retrace[:, ::-1]]),
                                                ("Current", "A", "both", [trace * 0, trace * 0])],
                     range_m=(3.2e-6, 2.0e-6), scan_time_s=(0.5, 0.5))
    listing = json.loads(runner.invoke(app, ["inspect", str(path), "--json"]).output)
    assert listing["format"] == "nanonis" and listing["channels"][1]["direction"] == "backward"
    out = tmp_path / "run"
    result = runner.invoke(app, ["diagnose", "--measured", str(path), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert result.output.splitlines()[0].startswith("grating.sxm: picked 'Z' forward/backward")
    record = load_images(path)
    np.testing.assert_allclose(record.retrace, retrace.astype(np.float32), rtol=1e-6)
    assert record.scan_size_m == pytest.approx((3.2e-6, 2.0e-6)) and record.line_rate_hz == pytest.approx(1.0)
    trace, retrace = _grating(lines=24, points=32)
    stopped = [trace.copy(), retrace[:, ::-1].copy()]
    for image in stopped:
        image[18:] = np.nan  # how Nanonis stores the lines of a frame stopped before its end
    record = load_images(write_sxm(tmp_path / "stopped.sxm", [("Z", "m", "both", stopped)], range_m=(3.2e-6, 2.4e-6)))
    assert record.shape == (18, 32) and record.unscanned_lines == 6
    assert record.scan_size_m[1] == pytest.approx(2.4e-6 * 18 / 24)


def test_nanoscope_32_bit_layers(tmp_path):
    rng = np.random.default_rng(5)
    raw = rng.integers(-2**30, 2**30, (8, 12)).astype(np.int32)
    path = write_nanoscope(tmp_path / "scan.spm", [("Height Sensor", "Trace", raw), ("Height Sensor", "Retrace", -raw)],
                            bytes_per_pixel=4)
    t, r, _ = pick_height_pair(read_afm_file(path))
    nm_per_lsb = 440.0 / 2**32 * 20.0
    np.testing.assert_allclose(t.data, raw * nm_per_lsb * 1e-9)
    np.testing.assert_allclose(r.data, -raw * nm_per_lsb * 1e-9)


def test_npz_run_images_and_plain_pair(tmp_path):
    trace, retrace = _grating()
    plain = tmp_path / "pair.npz"
    np.savez(plain, trace=trace, retrace=retrace, scan_size_m=[3.2e-6, 2.4e-6], line_rate_hz=5.0)
    afm = read_afm_file(plain)
    t, r, _ = pick_height_pair(afm)
    assert afm.format == "npz" and t.line_time_s == pytest.approx(0.1) and np.array_equal(r.data, retrace)
    run = tmp_path / "images.npz"
    np.savez(run, trace_none=trace, retrace_none=retrace, trace_diapi=trace, retrace_diapi=retrace,
             error_trace_diapi=trace / 10, error_retrace_diapi=retrace / 10,
             truth=trace[:8], image_pixel_size_m=[1e-7, 1e-7], image_origin_m=[0, 0],
             sample_pixel_size_m=[5e-8, 5e-8])
    channels = {(c.name, c.direction, c.quantity): c for c in read_afm_file(run).channels}
    assert set(channels) == {("none", "trace", "height"), ("none", "retrace", "height"), ("diapi", "trace", "height"),
                             ("diapi", "retrace", "height"), ("diapi", "trace", "deflection"),
                             ("diapi", "retrace", "deflection"), ("truth", "", "height")}
    assert channels["none", "trace", "height"].size_m == pytest.approx((3.2e-6, 2.4e-6))
    assert channels["truth", "", "height"].size_m == pytest.approx((1.6e-6, 0.4e-6))
    assert pick_height_pair(read_afm_file(run), "diapi")[0].name == "diapi"
    with_error, without = (load_images(run, channel=c, line_rate_hz=2.0) for c in ("diapi", "none"))
    assert np.array_equal(with_error.error_retrace, retrace / 10) and without.error_trace is None  # each its own
    np.savez(plain, trace=trace, retrace=retrace, scan_size_m=[3.2e-6, 2.4e-6], line_rate_hz=5.0,
             error_trace=trace / 10, error_retrace=retrace / 10)
    record = load_images(plain)
    assert record.error_channel == "deflection error (m)" and np.array_equal(record.error_trace, trace / 10)


def test_afmsim_own_images_come_through_the_shared_readers(tmp_path):
    """A plain trace/retrace .npz and a .gwy titled trace/retrace (what afmsim writes) are one
    'height' pair with the window's corner as offset, and load_images takes both from there."""
    from afmsim.report.gwy import write_gwy
    from afmsim.samples.heightmap import HeightMap

    trace, retrace = _grating()
    pixel, corner = (1e-7, 1e-7), (2e-6, 3e-6)
    plain = tmp_path / "pair.npz"
    np.savez(plain, trace=trace, retrace=retrace, scan_size_m=[3.2e-6, 2.4e-6], scan_offset_m=corner)
    maps = {k: HeightMap(z, pixel, (corner[0] + pixel[0] / 2, corner[1] + pixel[1] / 2))
            for k, z in (("trace", trace), ("retrace", retrace))}
    titled = write_gwy(tmp_path / "pair.gwy", maps, meta={"line rate (Hz)": "2.5"})
    for path in (plain, titled):
        t, r, picked = pick_height_pair(read_afm_file(path))
        assert (t.name, t.direction, r.direction) == ("height", "trace", "retrace") and "'height'" in picked
        assert t.offset_m == pytest.approx(corner) and t.size_m == pytest.approx((3.2e-6, 2.4e-6))
        record = load_images(path, line_rate_hz=4.0)
        np.testing.assert_array_equal(record.retrace, retrace)
        assert record.scan_offset_m == pytest.approx(corner) and record.picked is None
    assert load_images(titled).line_rate_hz == pytest.approx(2.5)  # recorded by the run, when no scenario says
    with pytest.raises(ReaderError, match="scan_offset_m must be 2"):
        np.savez(plain, trace=trace, retrace=retrace, scan_size_m=[3.2e-6, 2.4e-6], scan_offset_m=[1e-6])
        read_afm_file(plain)


# --- bad input: one line, exit 2, nothing written ----------------------------------------------------

def _bad_files(tmp_path):
    png = b"\x89PNG\r\n\x1a\n" + bytes(200)
    random = np.random.default_rng(7).integers(0, 256, 4000, dtype=np.uint8).tobytes()
    files = {"empty.nid": b"", "picture.nid": png, "noise.nid": random, "noise.ibw": random, "noise.spm": random,
             "noise.gwy": random, "noise.tiff": random, "noise.jpk": random, "noise.003": b"\\*File list\r\n\\Version: 0x05120130\r\n", "table.xyz": b"1 2 3"}
    trace, retrace = _grating()
    made = [write_gwy(tmp_path / "made.gwy", [("Z forward", trace, "m", 1e-6, "m"), ("Z backward", retrace, "m", 1e-6, "m")]),
            write_ibw(tmp_path / "made.ibw", {"HeightTrace": trace, "HeightRetrace": retrace}, {"ScanRate": 1}),
            write_nanoscope(tmp_path / "made.spm", [("Height", "Trace", np.zeros((16, 16), np.int16))]),
            write_park(tmp_path / "made.tiff", np.zeros((16, 16), "<i2")),
            write_jpk(tmp_path / "made.jpk", [("Height", False, np.zeros((16, 16)), 1e-9, 0.0)])]
    for path in made:  # cut in half: gwyfile would loop forever, igor2 logs, pySPM reads past the end
        files[f"cut_{path.name}"] = path.read_bytes()[:path.stat().st_size // 2]
        path.unlink()
    for name, content in files.items():
        (tmp_path / name).write_bytes(content)
    return [tmp_path / name for name in files] + [tmp_path / "missing.nid"]


def test_bad_files_raise_one_line(tmp_path):
    for path in _bad_files(tmp_path):
        with pytest.raises(ReaderError) as info:
            read_afm_file(path)
        assert path.name in str(info.value) and "\n" not in str(info.value)


def test_bad_files_exit_2_in_inspect_and_diagnose_with_nothing_written(tmp_path):
    for path in _bad_files(tmp_path):
        result = runner.invoke(app, ["inspect", str(path)])
        assert result.exit_code == 2 and result.output.count("\n") == 1, result.output
        out = tmp_path / f"diag-{path.name}"
        result = runner.invoke(app, ["diagnose", "--measured", str(path), "--out", str(out)])
        assert result.exit_code == 2 and "Traceback" not in result.output, result.output
        assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("diag")) == []


# --- end to end on an instrument file (small, so that the image diagnosis stays fast) ------------------

def _made(fmt, path, trace, retrace):
    """The same trace/retrace pair (m) written as a Nanoscope, Asylum, JPK or Gwyddion file, line time 0.5 s."""
    if fmt == "spm":
        to_raw = lambda h: np.round(h / (440.0 / 65536 * 20.0 * 1e-9)).astype(np.int16)  # noqa: E731
        return write_nanoscope(path, [("Height", "Trace", to_raw(trace)), ("Height", "Retrace", to_raw(retrace))],
                                size_um=3.2, rate_hz=1.0)
    if fmt == "ibw":
        return write_ibw(path, {"HeightTrace": trace, "HeightRetrace": retrace},
                          {"FastScanSize": 3.2e-6, "SlowScanSize": 2.0e-6, "ScanRate": 1.0})
    if fmt == "jpk":
        return write_jpk(path, [("Height", False, np.round(trace / 1e-12), 1e-12, 0.0),
                                 ("Height", True, np.round(retrace / 1e-12), 1e-12, 0.0)], size_m=(3.2e-6, 2e-6))
    return write_gwy(path, [("Z-Axis forward", trace, "m", 3.2e-6, "m"), ("Z-Axis backward", retrace, "m", 3.2e-6, "m")],
                      meta={"Time/Line": "500ms"})


@pytest.mark.parametrize("fmt", ["spm", "ibw", "gwy", "jpk"])
def test_inspect_and_diagnose_measured_run_on_each_made_format(tmp_path, fmt, monkeypatch):
    trace, retrace = _grating(lines=20, points=32)
    path = _made(fmt, tmp_path / f"grating.{fmt}", trace, retrace)
    listing = json.loads(runner.invoke(app, ["inspect", str(path), "--json"]).output)
    assert [c["line_time_s"] for c in listing["channels"]] == pytest.approx([0.5, 0.5])
    reads = []
    monkeypatch.setattr(readers, "read_afm_file", lambda file: reads.append(Path(file).name) or read_afm_file(file))
    out = tmp_path / "diag"
    result = runner.invoke(app, ["diagnose", "--measured", str(path), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert reads == [path.name]  # read once: the pair is picked and the diagnosis run from the same read
    assert result.output.splitlines()[0].startswith(f"grating.{fmt}: picked ")
    report = json.loads((out / "diagnosis.json").read_text())
    assert "verdict" in report and (out / "summary.txt").exists()
    assert "picked" in json.dumps(json.loads((out / "manifest.json").read_text()))


def _nsfopen_examples() -> list:
    try:
        import NSFopen
    except ImportError:  # pragma: no cover - a declared dependency
        return []
    return sorted((Path(NSFopen.__file__).parent / "example").rglob("*.nid"))


@pytest.mark.skipif(not _nsfopen_examples(), reason="nsfopen's example files absent")
def test_every_nid_that_nsfopen_ships_is_listed_or_refused_in_one_line():
    """Real files nobody used to build the readers (nsfopen's examples: five not in ../shared, two of
    them from heads with no file there): each image file lists both directions of a height channel
    and picks one; the spectroscopy-only file is one line, exit 2."""
    images = 0
    for path in _nsfopen_examples():
        result = runner.invoke(app, ["inspect", str(path)])
        if "thermal" in path.name:
            assert result.exit_code == 2 and "no image channels" in result.output
            assert len(result.output.strip().splitlines()) == 1
            continue
        assert result.exit_code == 0, (path.name, result.output)
        assert "picked" in result.output and "forward/backward" in result.output, path.name
        images += 1
    assert images >= 8
