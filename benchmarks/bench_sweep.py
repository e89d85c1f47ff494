"""Sweep throughput: runs/s on a two-worker Dask LocalCluster vs the same runs one after another in one process.

The runs are small micro-lens scenarios (``--pixels`` square, one experiment, none/SPI/DIAPI)
with random scan widths and seeds; the cluster is :func:`afmsim.sweep.local_cluster`, the one
``afmsim sweep`` starts. Numba caches are warmed first in this process and on every worker, and
the cluster is started before the clock runs, so the figures compare steady-state throughput;
``run_sweep`` adds the sweep's own file work (checkpoints, tables, plot). 48 runs of ~0.6 s keep
the tail (one worker idle while the other finishes the last run) to a few per cent. Serial, Dask
and ``run_sweep`` rounds alternate so that a change in load hits all three; medians and best
times are reported, and ``dask_busy_workers`` (sum of the runs' own wall times over the Dask
round's wall time: 2.0 means both workers were busy all the time, whatever the load). The results
must equal the serial ones exactly (every run is seeded). The machine may be shared: the load
average before and after is recorded. Writes ``benchmarks/results/sweep.json``.

    python benchmarks/bench_sweep.py [--runs 48] [--workers 2] [--pixels 32] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import machine_info  # noqa: E402
from afmsim.runio import write_json  # noqa: E402
from afmsim.sweep import local_cluster, parse_sweep, run_one, run_sweep  # noqa: E402


def _sweep(runs: int, pixels: int):
    base = {"name": "bench", "experiments": 1, "sample": {"kind": "microlens"},
            "scan": {"size_um": [10.0, 10.0], "offset_um": [2.0, 2.0], "pixels": pixels, "lines": pixels},
            "controllers": ["none", "spi", "diapi"], "identification": {"range": "scan"}}
    return parse_sweep({"name": "bench", "seed": 5, "base": base, "random": {"draws": runs, "parameters": {
        "scan.size_um.0": {"uniform": [6.0, 12.0]}, "seed": {"integers": [0, 10**9]}}}})


def _warm(run):
    run_one(run)
    return os.getpid()


def _check_equal(serial: list[dict], rows: list[dict]) -> None:
    for a, b in zip(serial, rows, strict=True):
        differ = [k for k in a.keys() | b.keys() if k != "wall_s" and not (  # x != x: a NaN std of one experiment
            k in a and k in b and (a[k] == b[k] or (a[k] != a[k] and b[k] != b[k])))]
        if differ:
            raise SystemExit(f"run {a['run_id']}: Dask result differs from the serial one in {differ}: "
                             f"{[a.get(k) for k in differ]} vs {[b.get(k) for k in differ]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=48)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--pixels", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=3, help="alternating serial / Dask / run_sweep rounds")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "sweep.json")
    args = parser.parse_args()
    from dask.distributed import Client

    sweep = _sweep(args.runs, args.pixels)
    runs = sweep.runs()
    load_before = os.getloadavg()
    _warm(runs[0])                                                         # numba caches of this process
    times, busy = {"serial": [], "dask": [], "run_sweep": []}, []
    with local_cluster(args.workers) as cluster, Client(cluster) as client, \
            tempfile.TemporaryDirectory() as folder:
        client.run(_warm, runs[0])                                         # every worker: imports, numba caches
        for k in range(args.repeats):                                      # alternate: load changes hit all three
            start = time.perf_counter()
            serial = [run_one(run) for run in runs]
            times["serial"].append(time.perf_counter() - start)
            start = time.perf_counter()
            rows = client.gather(client.map(run_one, runs, pure=False))
            times["dask"].append(time.perf_counter() - start)
            busy.append(sum(row["wall_s"] for row in rows) / times["dask"][-1])
            _check_equal(serial, rows)
            start = time.perf_counter()
            table = run_sweep(sweep, Path(folder) / f"sweep-{k}", scheduler=cluster.scheduler_address)
            times["run_sweep"].append(time.perf_counter() - start)
            if not np.array_equal(table["diapi.nsl2_mean"], [r["diapi.nsl2_mean"] for r in serial]):
                raise SystemExit("run_sweep table differs from the serial runs")
    load_after = os.getloadavg()
    median = {mode: float(np.median(t)) for mode, t in times.items()}
    best = {mode: float(np.min(t)) for mode, t in times.items()}
    result = {
        "benchmark": f"{len(runs)} runs of a {args.pixels}x{args.pixels} micro-lens scenario (1 experiment, "
                     f"none/spi/diapi): Dask LocalCluster ({args.workers} processes x 1 thread) vs serial, "
                     f"{args.repeats} alternating rounds",
        "runs": len(runs), "workers": args.workers, "seconds": times,
        "runs_per_s_median": {mode: len(runs) / t for mode, t in median.items()},
        "speedup_median": {"dask": median["serial"] / median["dask"], "run_sweep": median["serial"] / median["run_sweep"]},
        "speedup_best": {"dask": best["serial"] / best["dask"], "run_sweep": best["serial"] / best["run_sweep"]},
        "dask_busy_workers_median": float(np.median(busy)),
        "target_speedup": 1.7, "target_met_median": bool(median["serial"] / median["run_sweep"] >= 1.7),
        "mean_run_s": float(np.mean([r["wall_s"] for r in serial])),
        "results_equal_serial": True,
        "load_average_1_5_15min": {"before": load_before, "after": load_after},
        "machine": machine_info(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json(args.out, result)
    print(json.dumps({k: result[k] for k in ("seconds", "runs_per_s_median", "speedup_median", "speedup_best",
                                             "dask_busy_workers_median", "load_average_1_5_15min")}, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
