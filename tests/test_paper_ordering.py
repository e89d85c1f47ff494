"""The paper's Table 3 ordering D_N ≫ D_S > D_A in the regime where afmsim reproduces it, and the
ordering the paper's own protocol gives (DIAPI behind SPI and behind no compensation).

``scenarios/microlens_full_range.yaml`` scans ~90 % of the 100 µm identification loop; there
DIAPI's trace/retrace weights transfer to the scan and it must beat SPI by e_D ≥ 20 % (paper
44.3 %), with both far below the uncompensated NSL2. A smaller copy (fewer pixels and lines, two
experiments) keeps the test fast; the e_D of the bundled scenario is in docs/reference-results.md.
"""

from pathlib import Path

import pytest

from afmsim.experiment import run_scenario
from afmsim.scenario import load_scenario, parse_scenario

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
SCENARIO = SCENARIOS / "microlens_full_range.yaml"


def test_full_range_microlens_reproduces_paper_ordering():
    base = load_scenario(SCENARIO).model_dump(mode="json")
    small = {**base, "experiments": 2, "controllers": ["none", "spi", "diapi"],
             "scan": {**base["scan"], "pixels": 192, "lines": 24}}
    metrics = run_scenario(parse_scenario(small)).metrics()
    nsl2 = {name: scores["nsl2"]["mean"] for name, scores in metrics["controllers"].items()}
    assert nsl2["none"] > 5 * nsl2["spi"]
    assert nsl2["spi"] > nsl2["diapi"]
    assert metrics["e_D"] >= 0.20


@pytest.mark.parametrize("scenario", ["paper_protocol_microlens.yaml", "paper_protocol_microlens_duhem.yaml"])
def test_paper_protocol_puts_diapi_behind_no_compensation_on_both_minor_loop_laws(scenario):
    """The paper's own protocol (identify once on the 100 µm, 9.1 V loop, scan 30 µm): on both plant
    laws DIAPI's NSL2 is above SPI's *and* above the uncompensated scan's (docs/reference-results.md: full run 45,008 vs none 26,585 on Preisach, 88,814 vs 59,607 on Duhem). A reduced copy
    (128 × 32 px, two experiments) keeps it fast."""
    base = load_scenario(SCENARIOS / scenario).model_dump(mode="json")
    small = {**base, "experiments": 2, "controllers": ["none", "spi", "diapi"],
             "scan": {**base["scan"], "pixels": 128, "lines": 32}}
    metrics = run_scenario(parse_scenario(small)).metrics()
    nsl2 = {name: scores["nsl2"]["mean"] for name, scores in metrics["controllers"].items()}
    assert nsl2["diapi"] > 1.3 * nsl2["none"]
    assert nsl2["diapi"] > 1.5 * nsl2["spi"]
    assert metrics["e_D"] < -0.5
