"""Parallel scans: a run on several worker processes gives the serial run's bits."""

import numpy as np

from afmsim.experiment import run_scenario
from afmsim.scenario import parse_scenario


def test_parallel_scans_equal_serial_bits():
    scenario = parse_scenario({"name": "par", "seed": 3, "sample": {"kind": "microlens"},
                               "scan": {"size_um": [20, 20], "offset_um": [2, 2], "pixels": 32, "lines": 32},
                               "experiments": 2, "controllers": ["none", "spi", "diapi"]})
    stages = []
    serial = run_scenario(scenario, workers=1)
    parallel = run_scenario(scenario, workers=2, progress=lambda stage, done, total: stages.append((stage, done, total)))
    assert parallel.timings["workers"] == 2 and serial.timings["workers"] == 1
    assert parallel.metrics() == serial.metrics()          # exact equality, every float
    for name, images in serial.images.items():
        np.testing.assert_array_equal(parallel.images[name].trace.z, images.trace.z)
        np.testing.assert_array_equal(parallel.images[name].retrace.z, images.retrace.z)
    assert [s for s in stages if s[1] == s[2]] == [("sample", 1, 1), ("identify", 2, 2), ("scan", 6, 6), ("metrics", 6, 6)]
    assert all(0 <= done <= total for _, done, total in stages)
    assert set(parallel.timings) >= {"simulate_s", "metrics_s"} and parallel.timings["simulate_s"] > 0
