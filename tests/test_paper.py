"""The paper's numbers live in afmsim.paper; the printed means agree with the per-experiment rows."""

import numpy as np
import pytest

from afmsim import paper


@pytest.mark.parametrize("model", ["spi", "diapi"])
@pytest.mark.parametrize("stat", ["rms_V", "max_V"])
def test_table2_means_are_the_rows_means(model, stat):
    assert np.mean(paper.TABLE2[model][stat]) == pytest.approx(paper.TABLE2_MEANS[model][stat], abs=6e-4)


def test_table2_ratio_and_table1_asymmetry_follow_the_printed_values():
    assert paper.TABLE2_MEANS["diapi"]["rms_V"] / paper.TABLE2_MEANS["spi"]["rms_V"] == \
        pytest.approx(paper.TABLE2_RATIO, abs=0.005)
    for _, _, w_af, w_ab, e_w in paper.TABLE1:  # eq. (7), |e_ω| to the printed two digits
        assert abs((w_af - w_ab) / w_ab) == pytest.approx(e_w, abs=0.02)


@pytest.mark.parametrize("table", [paper.TABLE3, paper.TABLE4])
def test_e_d_is_eq9_of_the_table_means(table):
    assert (table["D_S"] - table["D_A"]) / table["D_S"] == pytest.approx(table["e_D"], abs=1e-3)


def test_reports_and_identification_read_the_same_module():
    from afmsim import identification
    from afmsim.report import tables

    assert identification.TABLE2_MEANS is paper.TABLE2_MEANS
    assert tables.PAPER_TABLE3 is paper.TABLE3 and tables.PAPER_TABLE4 is paper.TABLE4


def test_scenario_identification_defaults_are_the_papers_protocol():
    from afmsim.scenario import IdentificationSpec

    spec = IdentificationSpec()
    for key in ("amplitude_V", "frequency_hz", "sample_rate_hz"):
        assert getattr(spec, key) == paper.IDENTIFICATION_PROTOCOL[key]
