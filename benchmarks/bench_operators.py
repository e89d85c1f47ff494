"""Operator-update throughput of the OSP kernel (paper eq. 2): compiled vs naive numpy loop.

Measures M×N operator updates per second for M = 10⁶ samples and N = 10 operators, median of
``--repeats`` runs, for the compiled kernel (output allocation included) and the per-sample numpy
reference loop in the same run, checks that both give the same result, and writes
``benchmarks/results/operators.json``.

    python benchmarks/bench_operators.py [--samples 1000000] [--operators 10] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import machine_info, median_seconds  # noqa: E402
from afmsim.hysteresis import osp, osp_reference  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--operators", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "operators.json")
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    d = np.cumsum(rng.normal(0.0, 1e-7, args.samples))  # a random-walk displacement, metres
    widths = np.linspace(0.0, np.ptp(d), args.operators, endpoint=False)
    updates = args.samples * args.operators

    osp(d[:10], widths)  # compile / load from the on-disk cache outside the timing
    compiled_s, _ = median_seconds(lambda: osp(d, widths), args.repeats)
    naive_s, _ = median_seconds(lambda: osp_reference(d, widths), args.repeats)
    max_diff = float(np.max(np.abs(osp(d, widths) - osp_reference(d, widths))))
    if max_diff > 1e-12:
        raise SystemExit(f"compiled and reference kernels disagree by {max_diff}")

    result = {
        "benchmark": "osp operator updates per second",
        "samples_M": args.samples, "operators_N": args.operators, "repeats": args.repeats,
        "compiled_updates_per_s": updates / compiled_s,
        "naive_numpy_updates_per_s": updates / naive_s,
        "speedup": naive_s / compiled_s,
        "max_abs_difference_m": max_diff,
        "machine": machine_info(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"compiled {result['compiled_updates_per_s']:.3g} updates/s, naive {result['naive_numpy_updates_per_s']:.3g} "
          f"updates/s, speed-up {result['speedup']:.0f}x -> {args.out}")


if __name__ == "__main__":
    main()
