"""The time a user waits for ``afmsim run``: the quick run and the main job, stage by stage.

Each case runs the command line as a user types it (``python -m afmsim run SCENARIO``, a fresh
process, default ``--renders key``, every core) and reads the stage times it records in its
``manifest.json`` (``timings``: ``simulate_s`` = sample, identification and scans; ``metrics_s`` =
scores; ``report_s`` = every file, figure, render and the report; ``total_s`` = from the
command's start, after Python and afmsim are imported, to the manifest) plus the process's whole
wall time (``wall_s``, imports included) and CPU time (``cpu_s``: user + system of the process and
all its workers; unlike the wall times it hardly depends on the machine's load). The main job
also runs with ``--workers 1``: the scans' parallel speed-up, and a check that both give the same
``metrics.json``. Targets (issue 14, on the
2-core machine): quick ``total_s`` ≤ 3 × its ``simulate_s``; main job ``report_s`` ≤ its
``simulate_s``. The quick run is also timed with ``--renders none`` (what the render process
adds: VTK's start-up, overlapping the simulation, and three renders). The machine may be shared:
the load average around each case is recorded.
Writes ``benchmarks/results/run.json``.

    python benchmarks/bench_run.py [--repeats 2] [--skip-main]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import machine_info  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def run_case(scenario: str, *extra: str) -> dict:
    """One ``afmsim run`` in a fresh process: the manifest's timings, the wall time, the load."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        load_before = os.getloadavg()[0]
        cpu_before = _children_cpu()
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "afmsim", "run", str(ROOT / scenario), "--out", str(out), "-q", *extra],
                       check=True, capture_output=True, cwd=ROOT)
        wall = time.perf_counter() - start
        cpu = _children_cpu() - cpu_before
        timings = json.loads((out / "manifest.json").read_text())["timings"]
        metrics = json.loads((out / "metrics.json").read_text())["controllers"]
    return {**timings, "wall_s": wall, "cpu_s": cpu, "load_before": load_before, "load_after": os.getloadavg()[0],
            "_metrics": metrics}


def _children_cpu() -> float:
    """CPU seconds (user + system) of every finished child process and its descendants."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def summary(cases: list[dict]) -> dict:
    keys = ("simulate_s", "metrics_s", "report_s", "total_s", "wall_s", "cpu_s")
    return {"median": {k: statistics.median(c[k] for c in cases) for k in keys},
            "runs": [{k: v for k, v in c.items() if not k.startswith("_")} for c in cases]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--skip-main", action="store_true")
    args = parser.parse_args()
    results = {"machine": machine_info(), "cores": len(os.sched_getaffinity(0))}
    run_case("scenarios/quick.yaml")  # numba caches and the file cache warm
    quick = summary([run_case("scenarios/quick.yaml") for _ in range(args.repeats)])
    m = quick["median"]
    quick["total_over_simulate"] = m["total_s"] / m["simulate_s"]
    quick["target_met"] = m["total_s"] <= 3 * m["simulate_s"]
    results["quick"] = quick
    # the same without 3D renders: what the renders' process (VTK start-up + 3 renders) adds
    bare = summary([run_case("scenarios/quick.yaml", "--renders", "none") for _ in range(args.repeats)])
    bare["total_over_simulate"] = bare["median"]["total_s"] / bare["median"]["simulate_s"]
    results["quick_renders_none"] = bare
    if not args.skip_main:
        parallel = run_case("scenarios/microlens.yaml")
        serial = run_case("scenarios/microlens.yaml", "--workers", "1")
        main_job = summary([parallel])
        main_job["serial"] = summary([serial])
        main_job["report_over_simulate"] = parallel["report_s"] / parallel["simulate_s"]
        main_job["target_met"] = parallel["report_s"] <= parallel["simulate_s"]
        main_job["scan_speedup"] = serial["simulate_s"] / parallel["simulate_s"]
        main_job["same_metrics_serial_and_parallel"] = serial["_metrics"] == parallel["_metrics"]
        results["main"] = main_job
    out = ROOT / "benchmarks" / "results" / "run.json"
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps({k: v for k, v in results.items() if k != "machine"}, indent=2))


if __name__ == "__main__":
    main()
