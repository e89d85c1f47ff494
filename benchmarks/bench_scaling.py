"""How the scan loop's wall time and peak memory grow with the image size, 128² → 1024² pixels.

Each size runs in a fresh subprocess (so that its peak resident memory is its own) on the
``bench_realtime`` set-up: the micro-lens scenario at 1 Hz with all physics on, DIAPI feedforward,
one thread. Per size: the median wall time of ``--repeats`` ``scan_frame`` calls after a warm-up,
the peak of the numpy/Python memory the frame allocates (``tracemalloc``, above what was held
before the call) and the process's peak resident set (``resource.getrusage``, set-up included).
The log-log slope of each against the pixel count is fitted over all sizes; the script exits
non-zero if any slope exceeds 1.1 (growth faster than the pixel count). Writes
``benchmarks/results/scaling.json`` and ``benchmarks/results/scaling.png``.

    python benchmarks/bench_scaling.py [--sizes 128 256 512 1024] [--repeats 3]

The 1024² set-up (ray casting and dilating a 3346² sample grid) takes about a minute.
"""

from __future__ import annotations

import os

for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
MAX_SLOPE = 1.1
MEASURES = {"wall_s": "wall time of scan_frame (s)", "scan_peak_bytes": "peak memory allocated by scan_frame (bytes)",
            "process_peak_rss_bytes": "peak resident set of the process (bytes)"}


def measure_size(pixels: int, repeats: int) -> dict:
    """One size, in this process: wall time, the frame's own peak allocation and the peak RSS."""
    from _timing import median_seconds
    from bench_realtime import build_scan

    setup = build_scan(pixels)
    setup.scan()                                    # warm-up
    wall, _ = median_seconds(setup.scan, repeats)
    tracemalloc.start()
    held = tracemalloc.get_traced_memory()[0]
    setup.scan()
    peak = tracemalloc.get_traced_memory()[1] - held
    tracemalloc.stop()
    return {"pixels": pixels, "pixel_count": pixels * pixels, "samples": int(setup.trajectory.t.size),
            "instrument_time_s": setup.instrument_time_s, "wall_s": wall,
            "real_time_factor": setup.instrument_time_s / wall, "scan_peak_bytes": int(peak),
            "process_peak_rss_bytes": int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024,
            "load_average_1min_after": os.getloadavg()[0]}


def loglog_slope(x, y) -> float:
    """Least-squares slope of log(y) against log(x)."""
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def plot(rows: list[dict], path: Path) -> None:
    """Wall time and memory against pixel count, log-log, with slope-1 guides."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.array([r["pixel_count"] for r in rows], dtype=float)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    panels = ((axes[0], [("wall_s", 1.0, "wall time (s)")]),
              (axes[1], [("scan_peak_bytes", 2.0**-20, "scan_frame peak allocation (MiB)"),
                         ("process_peak_rss_bytes", 2.0**-20, "process peak RSS (MiB)")]))
    for ax, series in panels:
        for key, scale, label in series:
            y = np.array([r[key] for r in rows]) * scale
            ax.loglog(n, y, "o-", label=f"{label}, slope {loglog_slope(n, y):.2f}")
            ax.loglog(n, y[0] * n / n[0], ":", color="grey")
        ax.set_xlabel("pixels per image")
        ax.legend(fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("seconds")
    axes[1].set_ylabel("MiB")
    fig.suptitle("scan loop vs image size (dotted: proportional to the pixel count)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512, 1024])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--child", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=HERE / "results" / "scaling.json")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure_size(args.child, args.repeats)))
        return
    if len(args.sizes) < 2:
        raise SystemExit("--sizes: give at least two sizes to fit a slope")

    from _timing import machine_info

    rows = []
    for pixels in sorted(args.sizes):
        done = subprocess.run([sys.executable, __file__, "--child", str(pixels), "--repeats", str(args.repeats)],
                              capture_output=True, text=True, check=True)
        rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
        print(f"{pixels}²: {rows[-1]['wall_s']:.3f} s, scan peak {rows[-1]['scan_peak_bytes'] / 2**20:.0f} MiB, "
              f"process peak RSS {rows[-1]['process_peak_rss_bytes'] / 2**20:.0f} MiB", flush=True)
    counts = [r["pixel_count"] for r in rows]
    slopes = {key: loglog_slope(counts, [r[key] for r in rows]) for key in MEASURES}
    last_pair = {key: loglog_slope(counts[-2:], [r[key] for r in rows[-2:]]) for key in MEASURES}
    result = {"benchmark": "scan_frame wall time and peak memory vs image size (micro-lens, 1 Hz, all physics on, "
                           "DIAPI, one thread)",
              "measures": MEASURES, "sizes": rows, "loglog_slope_vs_pixel_count": slopes,
              "loglog_slope_largest_two_sizes": last_pair, "max_allowed_slope": MAX_SLOPE,
              "grows_no_faster_than_pixel_count": all(s <= MAX_SLOPE for s in slopes.values()),
              "machine": machine_info()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    plot(rows, args.out.with_suffix(".png"))
    print(json.dumps({"loglog_slope_vs_pixel_count": slopes, "loglog_slope_largest_two_sizes": last_pair}, indent=2))
    too_steep = {k: round(s, 3) for k, s in slopes.items() if s > MAX_SLOPE}
    if too_steep:
        raise SystemExit(f"grows faster than the pixel count (log-log slope > {MAX_SLOPE}): {too_steep}")


if __name__ == "__main__":
    main()
