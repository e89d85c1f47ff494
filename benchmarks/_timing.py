"""Shared helpers of the benchmark scripts: repeated timing and machine information."""

from __future__ import annotations

import os
import platform
import statistics
import time

import numpy as np


def median_seconds(func, repeats: int):
    """Median wall time (s) of ``repeats`` calls of ``func`` and the last call's return value."""
    times, value = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        value = func()
        times.append(time.perf_counter() - start)
    return statistics.median(times), value


def machine_info() -> dict:
    """Where a benchmark ran, for its results file."""
    return {"platform": platform.platform(), "processor": platform.machine(), "python": platform.python_version(),
            "cpu_count": os.cpu_count(), "numpy": np.__version__, "date": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
