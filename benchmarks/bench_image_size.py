"""Time and memory of an image diagnosis against the image's size (the 256 × 256 budget).

    PYTHONPATH=. python benchmarks/bench_image_size.py [--sizes 256 512 1024]

A real 256 × 256 Nanosurf pair (``../shared/real-data/afm/circles.nid``, skipped without it) is
resampled (bilinear) to each size and diagnosed in a child process of its own, so that each size's
peak memory is its own. Larger images are cut by
:func:`afmsim.diagnosis.images.record.within_budget` before the diagnosis. Writes
``benchmarks/results/image_size.json``: per size the wall time (s), the peak resident memory (GB),
the status and the gap, and the machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from _timing import machine_info

from afmsim.runio import write_json

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "real-data" / "afm" / "circles.nid"

CHILD = """
import json, sys, time
from scipy.ndimage import zoom
from afmsim.diagnosis import diagnose_images, load_images
from afmsim.readers import pick_height_pair, read_afm_file
trace, retrace, _ = pick_height_pair(read_afm_file(sys.argv[1]))
factor = int(sys.argv[2]) / trace.shape[0]
record = load_images({"trace": zoom(trace.data, factor, order=1), "retrace": zoom(retrace.data, factor, order=1),
                      "scan_size_m": trace.size_m, "line_rate_hz": 1.0 / (2.0 * trace.line_time_s)})
start = time.perf_counter()
report, _ = diagnose_images(record)
print(json.dumps({"seconds": time.perf_counter() - start, "status": report["status"],
                  "gap_to_noise": report["final"]["gap_to_noise"], "cut": report["images"].get("cut")}))
"""


def run_size(size: int) -> dict:
    """Diagnose ``circles.nid`` resampled to ``size`` × ``size`` in a child process."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(REAL), str(size)], stdout=subprocess.PIPE, env=env,
                             text=True)
    _, status, usage = os.wait4(child.pid, 0)
    out = json.loads(child.stdout.read().strip().splitlines()[-1]) if status == 0 else {"error": status}
    return {"size": size, **out, "peak_memory_gb": round(usage.ru_maxrss / 1e6, 2)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 512, 1024])
    args = ap.parse_args()
    if not REAL.exists():
        print(f"skipped: {REAL} is absent")
        return
    start = time.perf_counter()
    rows = [run_size(size) for size in args.sizes]
    for row in rows:
        print(f"{row['size']:>5} px: {row.get('seconds', float('nan')):6.1f} s, {row['peak_memory_gb']:.2f} GB, "
              f"{row.get('status')} {row.get('gap_to_noise')}")
    write_json(ROOT / "benchmarks" / "results" / "image_size.json",
               {"machine": machine_info(), "source": REAL.name, "rows": rows,
                "wall_s": round(time.perf_counter() - start, 1)})


if __name__ == "__main__":
    main()
