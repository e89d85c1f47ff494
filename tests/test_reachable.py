"""Scans the stage can reach (issue 14): a field beyond the stage's travel is refused up front, and
any drive that sits at its amplifier limit during a run is counted and reported."""

import numpy as np
import pytest

from afmsim.compensation import NominalLinear
from afmsim.experiment import run_scenario
from afmsim.scan import RasterGeometry, ZFeedback, ZStage, raster_trajectory, scan_frame
from afmsim.samples import HeightMap
from afmsim.scenario import ScenarioError, load_scenario, parse_scenario
from afmsim.stage import HYSTERESIS_MODELS, default_stage

UM = 1e-6
TINY = {"name": "tiny", "seed": 5, "experiments": 1, "sample": {"kind": "microlens"},
        "scan": {"size_um": [12, 12], "offset_um": [2, 2], "pixels": 32, "lines": 8},
        "numerics": {"approach_s": 0.2}, "controllers": ["none", "spi"]}


def _scenario(**blocks):
    return {**TINY, **{k: {**TINY.get(k, {}), **v} if isinstance(v, dict) else v for k, v in blocks.items()}}


@pytest.mark.parametrize("family", sorted(HYSTERESIS_MODELS))
def test_the_travel_is_the_calibrated_full_range_of_every_plant_family(family):
    stage = default_stage(family)
    for axis in (stage.x, stage.y):
        p = axis.params.hysteresis
        assert axis.params.travel_m == pytest.approx(p.sensitivity_m_per_V * p.calibration_amplitude_V)
        assert axis.params.travel_m == pytest.approx(100 * UM)           # the paper's 100 µm stage


@pytest.mark.parametrize("axis, label", [(0, "x"), (1, "y")])
def test_a_field_beyond_the_travel_is_refused_naming_both_fields_and_the_travel(axis, label):
    offset, size = [2.0, 2.0], [12.0, 12.0]
    offset[axis], size[axis] = 95.0, 20.0
    with pytest.raises(ScenarioError) as caught:
        parse_scenario(_scenario(scan={"offset_um": offset, "size_um": size}))
    message = str(caught.value)
    assert message.startswith(f"scan.offset_um[{axis}] + scan.size_um[{axis}] = 95 + 20 = 115 µm exceeds "
                              f"the stage travel 100 µm ({label})"), message
    assert "\n" not in message


def test_a_field_that_ends_on_the_travel_is_accepted():
    parse_scenario(_scenario(scan={"offset_um": [2, 0], "size_um": [98, 100]}))
    with pytest.raises(ScenarioError, match=r"= 100.5 µm exceeds the stage travel 100 µm \(x\)"):
        parse_scenario(_scenario(scan={"offset_um": [2.5, 0], "size_um": [98, 100]}))


def test_a_twin_scenario_is_checked_against_its_instruments_travel(tmp_path):
    import yaml

    (tmp_path / "instrument.yaml").write_text(yaml.safe_dump({"name": "small", "fast_axis": {"travel_um": 50.0},
                                                              "slow_axis": {"travel_um": 150.0}}))
    def scenario(offset, size):
        path = tmp_path / "twin.yaml"
        path.write_text(yaml.safe_dump(_scenario(instrument="instrument.yaml",
                                                 scan={"offset_um": offset, "size_um": size})))
        return load_scenario(path)
    assert scenario([2, 2], [48, 98]).instrument == tmp_path / "instrument.yaml"   # 50 µm x, 100 µm y: fine
    with pytest.raises(ScenarioError, match=r"^scan.offset_um\[0\] \+ scan.size_um\[0\] = 2 \+ 50 = 52 µm exceeds "
                                            r"the instrument's travel 50 µm \(x\)"):
        scenario([2, 2], [50, 20])


def test_clipped_drive_samples_are_those_outside_the_amplifier_range():
    axis = default_stage().x
    v = np.array([-0.5, 0.0, 5.0, 10.0, 10.2, 12.0])
    assert axis.clipped(v).tolist() == [True, False, False, False, True, True]
    assert not axis.with_effects(saturation=False).clipped(v).any()   # nothing is clipped then


def _scan(offset_um: float, z_travel_m: float = 12 * UM):
    geometry = RasterGeometry(size=(20 * UM, 10 * UM), offset=(offset_um * UM, 2 * UM), pixels=32, lines=4,
                              samples_per_pixel=2, approach_s=0.2)
    z = np.zeros((300, 1300))
    z[:, 150:200] = 0.5 * UM                               # a 0.5 µm ridge at x = 10–15 µm
    surface = HeightMap(z, (0.1 * UM, 0.1 * UM), origin=(-5 * UM, -5 * UM))
    stage = default_stage()
    control = NominalLinear(stage.x.params.sensitivity_m_per_V)
    return scan_frame(surface, raster_trajectory(geometry), stage, control, control,
                      ZStage(max_voltage_V=z_travel_m / 0.6e-6), ZFeedback(), np.random.default_rng(2))


def test_a_scan_driven_past_the_stage_limit_counts_saturated_samples_and_a_reachable_one_none():
    inside, beyond = _scan(2.0), _scan(95.0)               # fast axis to 22 µm / to 115 µm (10 V ≈ 110 µm)
    assert inside.saturated == {"x": 0, "y": 0, "z": 0, "any": 0} and inside.saturated_fraction == 0.0
    assert beyond.saturated["x"] > 0 and beyond.saturated["y"] == 0
    assert beyond.samples == 4 * 2 * 32 * 2
    # the drive runs from 95 µm (8.6 V) to 115 µm (10.5 V): about the last quarter of each half-line is clipped
    assert 0.1 < beyond.saturated_fraction < 0.45
    # and where it is clipped the tip stands still: within a line, the image's last columns see one x
    stuck = np.ptp(beyond.actual_x_trace[:, -3:], axis=1)
    assert stuck.max() < 0.01 * np.ptp(beyond.actual_x_trace[0])
    assert np.ptp(inside.actual_x_trace[:, -3:], axis=1).min() > 0.5 * UM   # a reachable line moves on


def test_a_sample_taller_than_the_z_travel_counts_z_saturation():
    low = _scan(2.0, z_travel_m=0.4 * UM)                 # ±0.2 µm about mid-range, a 0.5 µm ridge
    assert low.saturated["z"] > 0 and low.saturated["x"] == low.saturated["y"] == 0
    assert low.saturated["any"] == low.saturated["z"]


def test_a_run_reports_saturation_per_controller_and_says_so_in_its_notes():
    normal = run_scenario(parse_scenario(_scenario())).metrics()
    for scores in normal["controllers"].values():
        assert scores["saturated_fraction"]["per_experiment"] == [0.0]
    assert not any("amplifier limit" in note for note in normal.get("notes", []))
    # a 1 µm lens under a Z stage of 0.5 µm travel: the Z drive pins (a valid scenario, nothing refused)
    pinned = run_scenario(parse_scenario(_scenario(z_stage={"travel_um": 0.5}))).metrics()
    fractions = {n: s["saturated_fraction"]["mean"] for n, s in pinned["controllers"].items()}
    assert all(0 < f < 1 for f in fractions.values()), fractions
    assert pinned["units"]["saturated_fraction"] == "1"
    note = next(n for n in pinned["notes"] if "amplifier limit" in n)
    assert all(f"{name} {f:.2%}" in note for name, f in fractions.items())
