"""Identification time of DIAPI (direct, Fig. 3b) vs IIAPI (three-step, Fig. 3a) — paper Fig. 8.

For every M (samples per hysteresis loop) and N (operators) in one run: a 1 Hz-style loop of
M samples (one period of a 0 … 100 V sine through a fixed asymmetric play-operator plant, after
one warm-up period) is identified by ``DIAPI.fit`` and by ``IIAPI.fit`` (forward fit + monotone
clipping + analytic inverse); (M, N) pairs with M < 8N are skipped (too few samples for
2N weights, ``check_fit_inputs``). Each timing is the median of ``--repeats`` runs, the two models
alternating. Time saving = (t_IIAPI − t_DIAPI)/t_IIAPI (the paper's Fig. 8 value is
``afmsim.paper.FIG8``). Correctness is checked in the same run: both inverse models must reproduce the loop's
voltage to < 2 % of its range, else the script exits non-zero. Writes
``benchmarks/results/identification_timing.json`` with machine info.

    python benchmarks/bench_identification.py [--repeats 30]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # single-threaded BLAS:
    os.environ.setdefault(_var, "1")  # small problems, and thread contention made timings erratic

import numpy as np  # noqa: E402
import scipy  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import afmsim  # noqa: E402
from afmsim.hysteresis import DIAPI, IIAPI, play  # noqa: E402
from afmsim.paper import FIG8  # noqa: E402

M_VALUES = (100, 200, 500, 1000, 2000)
N_VALUES = (5, 10, 15, 20)


def loop(m: int) -> tuple[np.ndarray, np.ndarray]:
    """One warm-up period + one measured period of M samples: displacement (m), voltage (V)."""
    phase = np.arange(2 * m) / m
    v = 50 - 50 * np.cos(2 * np.pi * phase)
    y = play(v, np.array([0.0, 5, 15, 30]), 0.0) @ np.array([0.6, 0.15, 0.1, 0.05])
    d = (y + 0.003 * y**2) * 1e-6
    return d[m:], v[m:]


def median_seconds(funcs, repeats: int) -> list[float]:
    times = [[] for _ in funcs]
    for _ in range(repeats):
        for k, func in enumerate(funcs):
            start = time.perf_counter()
            func()
            times[k].append(time.perf_counter() - start)
    return [statistics.median(t) for t in times]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "identification_timing.json")
    args = parser.parse_args()

    DIAPI.fit(*loop(100), n_operators=5)  # compile / load the operator kernel outside the timing
    IIAPI.fit(*loop(100), n_operators=5)
    rows = []
    for m in M_VALUES:
        d, v = loop(m)
        for n in N_VALUES:
            if m < 4 * 2 * n:  # both fits refuse fewer than 4 samples per weight (2N weights)
                rows.append({"M": m, "N": n, "skipped": f"M < 8N: too few samples for {2 * n} weights"})
                print(f"M={m:5d} N={n:2d}  skipped (M < 8N)")
                continue
            t_diapi, t_iiapi = median_seconds([lambda: DIAPI.fit(d, v, n_operators=n),
                                               lambda: IIAPI.fit(d, v, n_operators=n)], args.repeats)
            errors = {}
            for cls in (DIAPI, IIAPI):
                model = cls.fit(d, v, n_operators=n)
                errors[cls.name] = float(np.sqrt(np.mean((model.predict(d) - v) ** 2)))
                if errors[cls.name] > 0.02 * np.ptp(v):
                    raise SystemExit(f"{cls.name} M={m} N={n}: RMS error {errors[cls.name]:.3g} V is not a fit")
            rows.append({"M": m, "N": n, "diapi_fit_s": t_diapi, "iiapi_fit_s": t_iiapi,
                         "time_saving_percent": 100 * (t_iiapi - t_diapi) / t_iiapi,
                         "rms_error_V": errors})
            print(f"M={m:5d} N={n:2d}  DIAPI {t_diapi * 1e3:7.3f} ms  IIAPI {t_iiapi * 1e3:7.3f} ms  "
                  f"saving {rows[-1]['time_saving_percent']:5.1f} %")

    def mean_saving(key, value):
        return statistics.mean(r["time_saving_percent"] for r in rows if r[key] == value and "skipped" not in r)

    result = {
        "benchmark": "identification time, DIAPI (direct) vs IIAPI (forward fit + analytic inverse)",
        "paper": (f"Wang et al., Fig. 8: ~{100 * FIG8['saving_fraction_at_M200']:.0f} % saving at M = {FIG8['M']} "
                  f"(Matlab, i5, mean of {FIG8['runs']:,} runs)"),
        "repeats": args.repeats, "statistic": "median",
        "rows": rows,
        "saving_percent_by_M_mean_over_N": {str(m): mean_saving("M", m) for m in M_VALUES},
        "saving_percent_by_N_mean_over_M": {str(n): mean_saving("N", n) for n in N_VALUES},
        "saving_percent_at_M200_N10": next(r["time_saving_percent"] for r in rows if r["M"] == 200 and r["N"] == 10),
        "machine": {"platform": platform.platform(), "processor": platform.machine(),
                    "python": platform.python_version(), "cpu_count": os.cpu_count(),
                    "numpy": np.__version__, "scipy": scipy.__version__, "afmsim": afmsim.__version__},
        "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"saving at M=200, N=10: {result['saving_percent_at_M200_N10']:.1f} % -> {args.out}")


if __name__ == "__main__":
    main()
