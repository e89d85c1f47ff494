"""Validate the sim-to-real gap diagnosis on simulated cases and diagnose the real piezo record.

    PYTHONPATH=. python benchmarks/bench_diagnosis.py [--cases 30] [--seed 0]

Writes ``benchmarks/results/diagnosis.json``: the validation scores (top-1 accuracy, false alarms
on null cases, parameter recovery, held-out shrink vs the oracle, every case) and, when
``../shared/real-data`` exists beside the repository, the diagnosis of the real record.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from afmsim.diagnosis import diagnose_loops, validate_diagnosis

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "real-data" / "piezo-sine-150V-1Hz.csv"


def _jsonable(o):
    if isinstance(o, dict):
        return {k: _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    return o


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t0 = time.perf_counter()
    scores = validate_diagnosis(n_cases=args.cases, seed=args.seed)
    scores["wall_s"] = round(time.perf_counter() - t0, 1)
    out = {"validation": scores}
    if REAL.is_file():
        t0 = time.perf_counter()
        rep, summary = diagnose_loops(REAL)
        rep["record"]["source"] = "../shared/real-data/piezo-sine-150V-1Hz.csv"
        out["real_record"] = {"report": rep, "summary": summary, "wall_s": round(time.perf_counter() - t0, 2)}
        print(summary)
    path = ROOT / "benchmarks" / "results" / "diagnosis.json"
    path.write_text(json.dumps(_jsonable(out), indent=1))
    keys = ("top1_accuracy", "exact_set_accuracy", "false_alarm_rate", "param_within_25pct", "param_median_rel_error",
            "shrink_vs_oracle_median", "wall_s")
    print(json.dumps({k: scores[k] for k in keys}, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
