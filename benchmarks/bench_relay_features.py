"""Time of the loop diagnosis' relay-state columns (`relay_features`, the relay grid's kernel).

The relay grid's columns are built once per record and, for the dynamics candidate's drive place,
once per trial τ of the lagged drive: 40,000 samples of a sine with noise at 17 levels (153 relays),
the same in blocks of 4 (a decimated record), and 33 levels (561 relays); median of ``--repeats``
runs each, the compiled kernel loaded outside the timing. Writes
``benchmarks/results/relay_features.json``.

    python benchmarks/bench_relay_features.py [--samples 40000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import machine_info, median_seconds  # noqa: E402
from afmsim.diagnosis.loops.model import relay_features  # noqa: E402

CASES = ((17, 1), (17, 4), (33, 1))  # (levels, block)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=40_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "relay_features.json")
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    v = 5.0 * np.sin(np.linspace(0.0, 60.0, args.samples)) + 0.1 * rng.standard_normal(args.samples)  # volts
    relay_features(v[:10], float(v.min()), float(v.max()), 2)  # compile / load from the on-disk cache
    cases = []
    for levels, block in CASES:
        seconds, cols = median_seconds(lambda: relay_features(v, float(v.min()), float(v.max()), levels, block),
                                       args.repeats)
        cases.append({"levels": levels, "block": block, "relays": cols.shape[1], "rows": cols.shape[0],
                      "ms": round(seconds * 1e3, 2)})
        print(f"{levels} levels, block {block}: {cols.shape[1]} relays x {cols.shape[0]} rows in {seconds * 1e3:.1f} ms")
    result = {"benchmark": "relay_features wall time", "samples": args.samples, "repeats": args.repeats,
              "cases": cases, "machine": machine_info()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"-> {args.out}")


if __name__ == "__main__":
    main()
