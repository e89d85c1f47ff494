"""Validate the image-data diagnosis on simulated trace/retrace scans with withheld effects.

    PYTHONPATH=. python benchmarks/bench_image_diagnosis.py [--cases 32] [--seed 0] [--pixels 64]

Writes ``benchmarks/results/image_diagnosis.json``: the scores of
:func:`afmsim.diagnosis.validate_image_diagnosis` (top-1 accuracy, false alarms on null cases,
parameter recovery, held-out shrink vs the oracle, every case with its verdict and time), the wall
time and the machine. The reported run uses seed 0; the diagnosis was developed on seeds 101–102.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from _timing import machine_info

from afmsim.diagnosis import validate_image_diagnosis
from afmsim.runio import write_json

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", type=int, default=32)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pixels", type=int, default=64)
    args = ap.parse_args()
    t0 = time.perf_counter()
    scores = validate_image_diagnosis(n_cases=args.cases, seed=args.seed, pixels=args.pixels)
    scores["wall_s"] = round(time.perf_counter() - t0, 1)
    scores["machine"] = machine_info()
    path = ROOT / "benchmarks" / "results" / "image_diagnosis.json"
    write_json(path, scores)
    keys = ("n_cases", "top1_accuracy", "top1_accuracy_detectable", "exact_set_accuracy", "false_alarm_rate",
            "param_within_25pct", "param_median_rel_error", "shrink_vs_oracle_median", "wall_s")
    print(json.dumps({k: scores.get(k) for k in keys}, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
