"""Null records of hysteresis families outside the open-world suite (a probe, issue 11 point 3).

    PYTHONPATH=. nice -n 10 python benchmarks/bench_other_families.py [--seed 901] [--records 4] [--workers 2]

For each family of :data:`afmsim.diagnosis.loops.null_plants.OTHER_FAMILIES` (Coleman–Hodgdon,
Dahl, Jiles–Atherton, Maxwell slip, discrete Preisach grids of ideal relays of 10–40 and of 50–128
levels), ``--records`` null
records — no added effect — under the open-world suite's drives (:func:`afmsim.diagnosis.loops.open_world.record_drive`, its three timings
drawn), white sensor noise of 5–15 nm, no cross axis; each diagnosed in full as a user's record
would be. Writes ``benchmarks/results/other_families.json`` (the machine, the git revision, every
record's status, baseline family, held-out and training gap, verdict and time) and prints one line
per record. Seed 901 was the probe's own (docs/diagnosis.md, "Families outside the suite"): these
are development records, not validation.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from afmsim.diagnosis.loops import diagnose_record
from afmsim.diagnosis.loops.null_plants import OTHER_FAMILIES, null_plant
from afmsim.diagnosis.loops.open_world import TIMINGS, record_drive
from afmsim.diagnosis.loops.record import load_record
from afmsim.runio import git_revision, write_json

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import machine_info  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def run_record(seed: int, family: str, index: int) -> dict:
    """Simulate and diagnose null record ``index`` of ``family``; a JSON-able summary."""
    rng = np.random.default_rng([seed, sorted(OTHER_FAMILIES).index(family), index])
    timing = TIMINGS[int(rng.integers(len(TIMINGS)))]
    t, v, kind = record_drive(timing, rng)
    x = null_plant(family, v, np.random.default_rng(int(rng.integers(2**63))))
    sigma = float(rng.uniform(5e-9, 15e-9))
    start = time.perf_counter()
    report, _, _ = diagnose_record(load_record({"t_s": t, "v_V": v, "x_m": x + sigma * rng.standard_normal(t.size)}))
    base = report["baseline"]
    return {"family": family, "index": index, "timing": timing, "excitation": kind, "baseline_family": base["family"],
            "status": report["status"], "gap_to_noise": base["gap_to_noise"],
            "train_gap_to_noise": round(base["train_rms"] / base["noise_floor"], 3), "verdict": report["verdict"],
            "implausible": [f["effect"] for f in report["implausible"]], "reading": report["unexplained"].get("reading"),
            "seconds": round(time.perf_counter() - start, 1)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=901)
    ap.add_argument("--records", type=int, default=4)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "other_families.json")
    args = ap.parse_args()
    jobs = [(args.seed, family, k) for family in sorted(OTHER_FAMILIES) for k in range(args.records)]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        records = list(pool.map(run_record, *zip(*jobs)))
    for r in records:
        print(f"{r['family']:16s} {r['index']} {r['timing']:8s} {r['excitation']:9s} {r['baseline_family']:8s} "
              f"held out {r['gap_to_noise']:7.2f}×  training {r['train_gap_to_noise']:7.2f}×  {r['status']:16s} "
              f"{r['verdict']} {r['reading'] or ''}")
    out = {"machine": machine_info(), "git": git_revision(), "seed": args.seed, "records_per_family": args.records,
           "wall_s": round(time.perf_counter() - start, 1), "records": records}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json(args.out, out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
