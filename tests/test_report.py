"""Run reports: report.html/.md, NSL2 tables, .gwy export, 3D renders, ``afmsim render``, Fig. 8."""

import csv
import json
import re
import shutil

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from afmsim.cli import app
from afmsim.experiment import run_scenario
from afmsim.render import rendering_available
from afmsim.report.gwy import read_gwy
from afmsim.report.run_output import write_run
from afmsim.scenario import parse_scenario

CONTROLLERS = ["none", "spi", "diapi", "ideal"]
RENDERS = [f"render_{c}_{d}.png" for c in CONTROLLERS for d in ("trace", "retrace")] + ["render_sample.png"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    scenario = parse_scenario({"name": "tiny", "sample": {"kind": "microlens"},
                               "scan": {"size_um": [20, 20], "offset_um": [2, 2], "pixels": 32, "lines": 32},
                               "experiments": 1, "controllers": CONTROLLERS})
    result = run_scenario(scenario)
    folder = tmp_path_factory.mktemp("run")
    write_run(result, folder, renders="all", workers=2)
    return folder


def test_report_html_embeds_images(run_dir):
    page = (run_dir / "report.html").read_text(encoding="utf-8")
    uris = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    # 4 controller figures + binarized (+ 9 renders where rendering works)
    assert len(uris) >= 5
    assert all(u.startswith("iVBORw0KGgo") for u in uris)  # base64 of the PNG signature
    assert 'src="render_' not in page and 'src="figure_' not in page  # nothing linked from outside
    assert "kind: microlens" in page and "Table 3 (micro-lens)" in page


def test_report_md_has_table_with_paper_values(run_dir):
    md = (run_dir / "report.md").read_text(encoding="utf-8")
    for paper_value in ("45,814", "2,322", "1,293", "44.3 %"):
        assert paper_value in md
    assert "| experiment | none (D_N) | spi (D_S) | diapi (D_A) | ideal | e_D |" in md
    assert "](figure_diapi.png)" in md and "](figure_spi.png)" in md and "](binarized.png)" in md
    assert (run_dir / "nsl2_table.md").read_text() in md


def test_nsl2_csv_per_experiment_rows(run_dir):
    rows = list(csv.reader((run_dir / "nsl2_table.csv").open()))
    assert rows[0] == ["experiment", *CONTROLLERS, "e_D"]
    assert [r[0] for r in rows[1:]] == ["1", "mean", "std", "paper"]
    metrics = json.loads((run_dir / "metrics.json").read_text())
    for j, c in enumerate(CONTROLLERS, 1):
        assert float(rows[1][j]) == pytest.approx(metrics["controllers"][c]["nsl2"]["per_experiment"][0], rel=1e-5)
    assert rows[4][1:4] == ["45814", "2322", "1293"] and rows[4][5] == "0.443"


def test_gwy_round_trip(run_dir):
    channels = read_gwy(run_dir / "images.gwy")
    expected = [f"{d} {c}" for c in CONTROLLERS for d in ("trace", "retrace")] + ["topography"]
    expected += [f"error {d} {c}" for c in CONTROLLERS for d in ("trace", "retrace")]
    assert list(channels) == expected
    with np.load(run_dir / "images.npz") as arrays:
        for c in CONTROLLERS:
            assert channels[f"trace {c}"].shape == (32, 32)
            np.testing.assert_array_equal(channels[f"retrace {c}"].z, arrays[f"retrace_{c}"])
            np.testing.assert_array_equal(channels[f"error retrace {c}"].z, arrays[f"error_retrace_{c}"])
        assert channels["topography"].shape == arrays["truth"].shape
    from afmsim.diagnosis import load_images  # the diagnosis reads the error images from the .gwy too

    record = load_images(run_dir / "images.gwy", channel=CONTROLLERS[1], line_rate_hz=1.0)
    with np.load(run_dir / "images.npz") as arrays:
        np.testing.assert_array_equal(record.error_trace, arrays[f"error_trace_{CONTROLLERS[1]}"])


def test_paper_figures_written(run_dir):
    for name in [f"figure_{c}.png" for c in CONTROLLERS] + ["binarized.png"]:
        with Image.open(run_dir / name) as im:
            assert im.size[0] >= 800


def _check_renders(folder):
    for name in RENDERS:
        with Image.open(folder / name) as im:
            assert im.size[0] >= 800 and im.size[1] >= 600, name
            assert np.asarray(im).std() > 0, name


def test_renders_written(run_dir):
    ok, reason = rendering_available()
    if not ok:
        assert "3D renders skipped" in (run_dir / "report.md").read_text()
        pytest.skip(f"off-screen rendering impossible here: {reason}")
    _check_renders(run_dir)


def test_cli_render_recreates_renders(run_dir, tmp_path):
    ok, reason = rendering_available()
    if not ok:
        pytest.skip(f"off-screen rendering impossible here: {reason}")
    copy = tmp_path / "copy"
    shutil.copytree(run_dir, copy)
    for name in RENDERS:
        (copy / name).unlink()
    outcome = CliRunner().invoke(app, ["render", str(copy)])
    assert outcome.exit_code == 0, outcome.output
    _check_renders(copy)


def test_cli_render_rejects_non_run_folder(tmp_path):
    (tmp_path / "notes.txt").write_text("not a run")
    outcome = CliRunner().invoke(app, ["render", str(tmp_path)])
    assert outcome.exit_code == 2
    assert "not an afmsim run folder" in outcome.output
    assert len(outcome.output.strip().splitlines()) == 1


def test_fig8_time_saving(tmp_path):
    from afmsim.report.paper_figures import plot_time_saving

    timing = {"repeats": 3, "statistic": "median", "rows": [
        {"M": m, "N": n, "time_saving_percent": 40.0 - m / 100 + n / 10} for m in (100, 200, 500) for n in (5, 10)]
        + [{"M": 100, "N": 20, "skipped": "M < 8N"}]}
    source = tmp_path / "timing.json"
    source.write_text(json.dumps(timing))
    out = plot_time_saving(source, tmp_path / "fig8.png")
    with Image.open(out) as im:
        assert im.size[0] >= 800


def test_identification_report(tmp_path):
    from afmsim.identification import identify, write_identification

    result = identify(experiments=2, models=["spi", "diapi", "capi"])
    write_identification(result, tmp_path)
    for name in ("fig6_loops.png", "fig7_errors.png", "table2.md", "table2.csv", "table1.csv"):
        assert (tmp_path / name).is_file(), name
    rows = list(csv.reader((tmp_path / "table2.csv").open()))
    assert [r[0] for r in rows[1:]] == ["1", "2", "mean", "std", "paper"]
    assert rows[-1][1:3] == ["0.08", "0.021"]
    assert "paper RMS" in (tmp_path / "table2.md").read_text()
    assert len(list(csv.reader((tmp_path / "table1.csv").open()))) == 1 + result.settings["n_operators"]
    table1 = (tmp_path / "table1.md").read_text()
    assert "e_ω = |ω_af − ω_ab| / |ω_ab| (paper eq. 7)" in table1 and "| e_ω (eq. 7) |" in table1
    assert table1.count("\n| ") == 1 + result.settings["n_operators"]   # the header and one row per operator


def test_report_explains_itself_on_its_first_screen(run_dir):
    page = (run_dir / "report.html").read_text(encoding="utf-8")
    first = page[:page.index("<h2>Definitions</h2>")]          # what comes before any figure
    assert "What was run." in first and "micro-lens array" in first and "32 × 32 px" in first
    assert "Best compensation:" in first and "× ideal" in first and "paper NSL2" in first
    assert "NSL2 grows with the pixel count" in first and "32 × 32 = 1,024 pixels" in first
    assert "data:image/png" not in first and "kind: microlens" not in first
    metrics = json.loads((run_dir / "metrics.json").read_text())
    if metrics["e_D"] <= 0:
        assert "DIAPI is worse than SPI here" in first and "minor loops" in first
    definitions = page[page.index("<h2>Definitions</h2>"):page.index("<h2>Provenance</h2>")]
    for term in ("NSL2</b> (paper eq. 8)", "e_D</b> (eq. 9)", "shift x</b>", "negative = the retrace", "scale x</b>"):
        assert term in definitions, term
    provenance = page[page.index("<h2>Provenance</h2>"):]
    assert re.search(r"afmsim \S+, commit [0-9a-f]{12}|commit unknown", provenance) and "UTC" in provenance
    assert re.search(r"<details><summary>Scenario \(YAML\)</summary>\s*<pre>", page)
    assert "<details><summary>3D renders" in page or "3D renders skipped" in page
    assert "<figcaption><b>figure_none.png</b> — Controller none, experiment 1 (paper Fig. 10–13 analogue)" in page


def test_height_images_have_data_limits_and_out_of_range_markers():
    import matplotlib.pyplot as plt

    from afmsim.report.figures import run_colour_scales, show_height, substrate_level
    from afmsim.samples.heightmap import HeightMap

    rng = np.random.default_rng(0)
    z = np.full((40, 40), 500e-9) + rng.normal(0, 1e-9, (40, 40))
    z[10:20, 10:20] += 300e-9             # a feature
    z[30:, :] -= 60e-9                     # a dip below the substrate: 25 % of the pixels
    trace, retrace = HeightMap(z, (1e-7, 1e-7)), HeightMap(z + 2e-9, (1e-7, 1e-7))
    assert substrate_level(z) == pytest.approx(500e-9, abs=2e-9)   # the commonest level below the mean, not the dip
    scale = run_colour_scales({"c": (trace, retrace)})
    low, high = scale.height_nm
    assert low < -55 and 295 < high < 305                         # from the data, not from a fixed 0
    assert scale.height_extend == "both"                          # pixels beyond both percentiles: pointed ends
    fig, ax = plt.subplots()
    shown = show_height(ax, trace, scale.height_nm)
    assert shown.get_clim() == (low, high)
    assert tuple(shown.cmap.get_under()) != shown.cmap(0.0) and tuple(shown.cmap.get_over()) != shown.cmap(1.0)
    plt.close(fig)


def test_substrate_of_a_lens_array_is_its_flat_level_not_pulled_by_the_flanks():
    """Half the pixels below a lens array's mean lie on the lens flanks; the substrate is the flat."""
    from afmsim.report.figures import substrate_level

    rng = np.random.default_rng(5)
    y, x = np.mgrid[0:128, 0:128] * 0.1e-6                       # 12.8 µm field, 0.1 µm pixels
    z = np.zeros_like(x)
    for cx in (3.2e-6, 9.6e-6):
        for cy in (3.2e-6, 9.6e-6):
            r2 = (x - cx) ** 2 + (y - cy) ** 2
            z = np.maximum(z, 1e-6 * np.clip(1 - r2 / (3.2e-6) ** 2, 0, None))   # paraboloid caps, 1 µm high, 25 % flat
    z += 120e-9 + rng.normal(0, 0.5e-9, z.shape)
    below = z[z < z.mean()]
    assert np.median(below) > 120e-9 + 10e-9                      # the plain median of the lower part is biased
    assert substrate_level(z) == pytest.approx(120e-9, abs=1e-9)


def test_cli_run_records_timings_and_renders_none_writes_no_render(tmp_path):
    from pathlib import Path

    out = tmp_path / "run"
    scenario = Path(__file__).resolve().parents[1] / "scenarios" / "quick.yaml"
    outcome = CliRunner().invoke(app, ["run", str(scenario), "--out", str(out), "--experiments", "1",
                                       "--renders", "none"])
    assert outcome.exit_code == 0, outcome.output
    assert not list(out.glob("render_*.png"))
    assert (out / "figure_none.png").is_file() and not list(out.glob("image_*.png"))
    timings = json.loads((out / "manifest.json").read_text())["timings"]
    assert {"simulate_s", "metrics_s", "report_s", "total_s"} <= set(timings)
    assert 0 < timings["simulate_s"] < timings["total_s"] and timings["report_s"] < timings["total_s"]
    bad = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "bad"), "--renders", "some"])
    assert bad.exit_code == 2 and "--renders must be one of none, key, all" in bad.output
    assert not (tmp_path / "bad").exists()


def test_gwy_holds_every_experiment_with_line_rate_and_scenario(tmp_path):
    from gwyfile.objects import GwyObject

    scenario = parse_scenario({"name": "two", "sample": {"kind": "grating", "period_um": 5},
                               "scan": {"size_um": [15, 15], "offset_um": [2, 2], "pixels": 32, "lines": 32,
                                        "line_rate_hz": 2.0},
                               "experiments": 2, "controllers": ["none", "spi"]})
    write_run(run_scenario(scenario), tmp_path, renders="none")
    channels = read_gwy(tmp_path / "images.gwy")
    assert list(channels) == ["trace none", "retrace none", "trace spi", "retrace spi",
                              "trace none (experiment 2)", "retrace none (experiment 2)",
                              "trace spi (experiment 2)", "retrace spi (experiment 2)", "topography",
                              "error trace none", "error retrace none", "error trace spi", "error retrace spi"]
    assert not np.array_equal(channels["trace spi"].z, channels["trace spi (experiment 2)"].z)  # fresh noise
    meta = GwyObject.fromfile(str(tmp_path / "images.gwy"))["/4/meta"]
    assert float(meta["line rate (Hz)"]) == 2.0 and meta["scenario"] == "two"
    assert "period_um: 5.0" in meta["scenario (YAML)"]


def test_key_renders_share_one_exaggeration_and_the_substrate_reference(run_dir):
    from afmsim.report.figures import substrate_level
    from afmsim.report.renders import load_run_arrays, render_jobs

    _, images, truth = load_run_arrays(run_dir)
    jobs = render_jobs(images, truth, None, run_dir / "unused", which="key", best="spi")
    names = [args[1].name for _, args in jobs]
    assert names == ["render_none_trace.png", "render_spi_trace.png", "render_sample.png"]
    common = [args[3] for _, args in jobs]
    assert len({c["z_exaggeration"] for c in common}) == 1 and len({c["z_range_m"] for c in common}) == 1
    for _, args in jobs:                       # every map drawn above its own substrate level
        assert abs(substrate_level(args[0].z)) < 1e-12
    assert len(render_jobs(images, truth, None, run_dir, which="all")) == 2 * len(images) + 1


def _write_then_crash(_hmap, path):
    import faulthandler
    import os
    import signal

    faulthandler.disable()  # pytest's crash dump would only clutter the output
    path.write_bytes(b"half a PNG")
    os.kill(os.getpid(), signal.SIGSEGV)  # what a broken GL stack does


def _draw_blank(_hmap, path):
    from afmsim.render import RenderingUnavailable

    raise RenderingUnavailable(f"{path.name}: the off-screen render came out blank")


def test_a_render_process_that_crashes_leaves_a_warning_and_no_partial_file(tmp_path):
    """The renders run in a forked process of their own: its crash is a one-line warning naming
    the signal, the caller lives on, and no partial render file is left."""
    from functools import partial

    from afmsim.report.render_process import start_renders

    target = tmp_path / "render_none_trace.png"
    paths, warning = start_renders(partial(_write_then_crash, None, target), [target])()
    assert paths == [] and "signal 11" in warning and "3D renders skipped" in warning
    assert not target.exists()
    blank = tmp_path / "render_sample.png"
    paths, warning = start_renders(partial(_draw_blank, None, blank), [blank])()
    assert paths == [] and "came out blank" in warning and "\n" not in warning


def _write_marker(path):
    path.write_text("drawn")
    return [path]


def _hang(path):
    import time

    path.write_text("half")
    time.sleep(600)


def test_a_warm_render_process_draws_what_it_is_sent_and_a_hung_one_is_stopped(tmp_path, monkeypatch):
    """The render process started before the simulation draws the job sent later; one that hangs
    is killed after the timeout with a one-line warning and no partial file; one closed unused ends."""
    from functools import partial

    from afmsim.report import render_process
    from afmsim.report.render_process import RenderProcess

    target = tmp_path / "render_sample.png"
    process = RenderProcess(warm=False)
    assert process.submit(partial(_write_marker, target), [target])() == ([target], None)
    assert target.read_text() == "drawn"
    monkeypatch.setattr(render_process, "RENDER_TIMEOUT_S", 0.5)
    hung = tmp_path / "render_none_trace.png"
    paths, warning = RenderProcess(warm=False).submit(partial(_hang, hung), [hung])()
    assert paths == [] and "no render after 1 s" in warning and "\n" not in warning
    assert not hung.exists()
    unused = RenderProcess(warm=False)
    unused.close()
    assert not unused._process.is_alive() and unused._process.exitcode == 0


def test_a_scan_figure_redrawn_for_another_controller_shows_only_that_controller(tmp_path):
    """ScanFigure is built once per run and redrawn per controller: a redraw replaces the maps, the
    profiles and the markers of the previous controller instead of adding to them."""
    import matplotlib.pyplot as plt

    from afmsim.report.figures import run_colour_scales
    from afmsim.report.paper_figures import ScanFigure
    from afmsim.samples.heightmap import HeightMap

    y, x = np.mgrid[0:48, 0:48] * 0.25e-6
    lens = lambda cx: 1e-6 * np.clip(1 - ((x - cx) ** 2 + (y - 6e-6) ** 2) / (3e-6) ** 2, 0, None)  # noqa: E731
    pairs = {"a": (HeightMap(lens(5.8e-6), (0.25e-6, 0.25e-6)), HeightMap(lens(6.4e-6), (0.25e-6, 0.25e-6))),
             "b": (HeightMap(lens(6.0e-6), (0.25e-6, 0.25e-6)), HeightMap(lens(6.1e-6), (0.25e-6, 0.25e-6)))}
    with ScanFigure(pairs["a"][0], kind="microlens", scale=run_colour_scales(pairs)) as figure:
        counts = []
        for name, (trace, retrace) in pairs.items():
            figure.draw(trace, retrace, tmp_path / f"figure_{name}.png", title=name)
            counts.append([len(ax.get_lines()) + len(ax.patches) for ax in figure.fig.axes])
            np.testing.assert_allclose(figure.difference.get_array(), (trace.z - retrace.z) / 1e-9)
            assert figure.fig._suptitle.get_text() == name
        assert counts[0] == counts[1]
        with pytest.raises(ValueError, match="grid"):
            figure.draw(HeightMap(np.zeros((8, 8)), (1e-6, 1e-6)), HeightMap(np.zeros((8, 8)), (1e-6, 1e-6)),
                        tmp_path / "x.png", title="x")
    assert not plt.fignum_exists(figure.fig.number)
    assert (tmp_path / "figure_b.png").stat().st_size > 10_000


def test_progress_counts_figure_files_as_they_are_written(tmp_path):
    """Figures are drawn as one job per worker (each redrawing its share of the controllers) plus the
    binarized overview; the progress display still counts files, up to every figure the run writes."""
    scenario = parse_scenario({"name": "tiny", "sample": {"kind": "grating"},
                               "scan": {"size_um": [12, 12], "offset_um": [2, 2], "pixels": 24, "lines": 8},
                               "experiments": 1, "controllers": ["none", "spi", "ideal"]})
    seen = []
    write_run(run_scenario(scenario), tmp_path, renders="none", workers=2, progress=lambda *a: seen.append(a))
    figures = [(done, total) for stage, done, total in seen if stage == "figures"]
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert pngs == ["binarized.png", "figure_ideal.png", "figure_none.png", "figure_spi.png"]
    assert figures[-1] == (4, 4) and [d for d, _ in figures] == sorted(d for d, _ in figures)
