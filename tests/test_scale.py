"""Scale (magnification) metric: intended span over travelled span."""

import numpy as np
import pytest

from afmsim.metrics import scale_x


def test_a_stage_that_falls_short_magnifies_the_image():
    intended = np.linspace(2e-6, 32e-6, 64)
    lines = np.tile(1.5e-6 + (intended - 2e-6) * (23.8 / 30), (8, 1))
    assert scale_x(intended, lines, lines) == pytest.approx(30 / 23.8)
    assert scale_x(intended, np.tile(intended, (8, 1)), np.tile(intended, (8, 1))) == pytest.approx(1.0)


def test_scale_is_the_median_over_lines_and_both_directions():
    intended = np.linspace(0, 10e-6, 11)
    trace = np.tile(intended * 0.5, (5, 1))
    trace[0] *= 0.1                                   # one wild line does not move the median
    retrace = np.tile(intended * 0.5, (5, 1))
    assert scale_x(intended, trace, retrace) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="moved to \\+x"):
        scale_x(intended, -trace, -retrace)
