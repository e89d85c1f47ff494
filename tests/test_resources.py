"""Memory guard (issue 6): runs whose arrays would not fit are refused up front with the estimate;
the estimate scales with the pixel count and is close to a measured run's peak."""

import copy
import tracemalloc
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from afmsim.cli import app
from afmsim.experiment import run_scenario
from afmsim.resources import (available_memory, check_memory, estimate_memory, format_bytes, memory_breakdown,
                              preflight)
from afmsim.scenario import ScenarioError, load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parents[1]
QUICK = load_scenario(ROOT / "scenarios" / "quick.yaml").model_dump(mode="json")
runner = CliRunner()


def _scenario(**blocks):
    data = copy.deepcopy(QUICK)
    for key, value in blocks.items():
        data[key] = {**data[key], **value} if isinstance(value, dict) and key != "sample" else value
    return parse_scenario(data)


# 2048 × 2048 px at 64 samples per pixel: 5.4·10⁸ trajectory samples; with CAPI's 50 operators
# the N × 9n operator arrays alone are ≈ 1.8 TiB, more than any machine this runs on.
HUGE = dict(scan={"pixels": 2048, "lines": 2048}, numerics={"samples_per_pixel": 64},
            controllers=["none", "capi"], identification={"n_operators": 50})


def test_huge_scan_is_refused_by_validate_and_run_with_the_estimate(tmp_path):
    path = tmp_path / "huge.yaml"
    path.write_text(yaml.safe_dump(_scenario(**HUGE).model_dump(mode="json")))
    for command in (["validate", str(path)], ["run", str(path), "--out", str(tmp_path / "o")]):
        result = runner.invoke(app, command)
        assert result.exit_code == 2, result.output
        (line,) = result.stderr.splitlines()
        assert line.startswith("error: scan.pixels × scan.lines × numerics.samples_per_pixel")
        assert "needs ≈ 1.8 TiB" in line and "available" in line and "reduce scan.pixels/lines" in line
    assert [p.name for p in tmp_path.iterdir()] == ["huge.yaml"]


def test_check_memory_compares_with_the_available_memory():
    scenario = _scenario()
    needed = estimate_memory(scenario)
    assert check_memory(scenario, available=needed) == (needed, needed)
    with pytest.raises(ScenarioError, match=rf"needs ≈ {format_bytes(needed)}, 1.0 KiB available"):
        check_memory(scenario, available=1024)


def test_quick_scenario_passes_and_validate_reports_the_estimate():
    needed, available = preflight(_scenario())
    assert 10 * 2**20 < needed < 2 * 2**30
    assert available is None or available > 0
    result = runner.invoke(app, ["validate", str(ROOT / "scenarios" / "quick.yaml")])
    assert result.exit_code == 0
    assert f"needs ≈ {format_bytes(needed)} of memory" in result.stdout


def test_available_memory_is_a_plausible_byte_count():
    available = available_memory()
    assert available is None or 2**20 < available < 2**50


def test_estimate_grows_linearly_with_the_pixel_count():
    """Grating, pixels = lines = 256 → 512 → 1024 → 2048: 4× the pixels each step, 4× the estimate
    (less the fixed identification part)."""
    sizes = [estimate_memory(_scenario(sample={"kind": "grating"}, scan={"pixels": p, "lines": p}), report=False)
             for p in (256, 512, 1024, 2048)]
    ratios = [b / a for a, b in zip(sizes, sizes[1:])]
    assert all(3.6 < r < 4.05 for r in ratios), ratios


def test_microlens_estimate_grows_with_the_pixel_count():
    """Monotone, not linear: the mesh is fixed and the ray caster works in bounded chunks."""
    sizes = [estimate_memory(_scenario(scan={"pixels": p, "lines": p}), report=False) for p in (64, 256, 1024, 2048)]
    assert sizes == sorted(sizes) and sizes[-1] > 100 * sizes[0]


def test_estimate_names_the_sample_pitch_when_the_lens_mesh_explodes():
    scenario = _scenario(sample={"kind": "microlens", "diameter_um": 0.5, "sag_um": 0.1, "pitch_um": 0.5},
                         scan={"size_um": [100, 100], "offset_um": [0, 0]})
    assert memory_breakdown(scenario).dominant().fields == "sample.pitch_um"
    with pytest.raises(ScenarioError, match=r"^sample\.pitch_um: needs ≈ .* raise sample\.pitch_um"):
        check_memory(scenario, available=16 * 2**30)


def _measured_peak(scenario) -> int:
    run_scenario(scenario)          # compile/load the numba kernels outside the measurement
    tracemalloc.start()
    try:
        run_scenario(scenario)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("blocks", [
    {"scan": {"pixels": 32, "lines": 32}},                                           # micro-lens: the mesh dominates
    {"scan": {"pixels": 32, "lines": 32}, "numerics": {"samples_per_pixel": 64},     # grating: the trajectory dominates
     "sample": {"kind": "grating"}},
], ids=["microlens-32px", "grating-32px-spp64"])
def test_estimate_is_within_a_factor_2_of_the_measured_peak(blocks):
    scenario = _scenario(experiments=1, **blocks)
    measured = _measured_peak(scenario)
    estimated = estimate_memory(scenario, report=False)
    assert measured / 2 < estimated < 2 * measured, (format_bytes(estimated), format_bytes(measured))
