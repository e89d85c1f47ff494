"""Parallel scans: a run on several worker processes gives the serial run's bits; a worker that
dies is one clear line, not a traceback."""

import os
import signal

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

import afmsim.experiment as experiment
from afmsim.cli import app
from afmsim.experiment import run_scenario
from afmsim.scenario import parse_scenario
from afmsim.workers import WorkerDied, ordered_map, worker_pool


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


def _killed_on_two(k):
    """Piece 2 is killed as the out-of-memory killer kills (SIGKILL); the others return their index."""
    if k == 2:
        os.kill(os.getpid(), signal.SIGKILL)
    return k


def _exits(*_):
    os._exit(3)


def test_a_dying_worker_is_one_line_saying_how_not_a_broken_pool():
    assert ordered_map(None, _killed_on_two, [(0,), (1,)]) == [0, 1]
    with pytest.raises(WorkerDied) as info:
        with worker_pool(2) as executor:
            ordered_map(executor, _killed_on_two, [(k,) for k in range(6)])
    assert str(info.value) == ("a worker process died (killed by signal 9 (SIGKILL) — out of memory?); "
                               "run again with fewer workers (--workers 1)")
    with pytest.raises(WorkerDied, match=r"\(exited with status 3\)"):
        with worker_pool(2) as executor:
            ordered_map(executor, _exits, [(k,) for k in range(4)])


def test_afmsim_run_whose_scan_worker_dies_exits_2_with_one_line_and_no_run_folder(tmp_path, monkeypatch):
    scenario = {"name": "dies", "seed": 3, "experiments": 1, "sample": {"kind": "grating"},
                "scan": {"size_um": [6.0, 6.0], "offset_um": [2.0, 2.0], "pixels": 16, "lines": 16},
                "controllers": ["none", "spi"]}
    path = tmp_path / "dies.yaml"
    path.write_text(yaml.safe_dump(scenario))
    monkeypatch.setattr(experiment, "_scan_one", _exits)  # looked up when the scans are handed out
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", str(path), "--out", str(out), "--quiet", "--workers", "2",
                                      "--renders", "none"])
    assert result.exit_code == 2 and "Traceback" not in result.output, result.output
    assert [line for line in result.output.splitlines() if line.strip()] == [
        "error: a worker process died (exited with status 3); run again with fewer workers (--workers 1)"]
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".run")]
