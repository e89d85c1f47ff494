"""Scan-loop speed: one 256 × 256 trace+retrace frame with all stage physics on.

Times each part of one scan (controller feedforward, XY plant, surface lookup, Z loop) and the
whole ``scan_frame`` call (median of ``--repeats`` after a warm-up) on the ``bench_realtime``
set-up (``scenarios/microlens.yaml``, DIAPI feedforward, one thread), checks the frame (finite
heights; on the memory-free stage trace and retrace agree) and writes
``benchmarks/results/scan.json`` with the load average (the machine may be shared).
``bench_realtime.py`` times the 512 × 512 frame against the real-time target and
``bench_scaling.py`` the growth with image size.

    python benchmarks/bench_scan.py [--pixels 256] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from bench_realtime import build_scan  # first: it limits every thread pool to one thread and puts the repo on sys.path

import numpy as np  # noqa: E402

from _timing import machine_info, median_seconds as timed  # noqa: E402
from afmsim.metrics import image_shift  # noqa: E402
from afmsim.scan import surface_under_tip, track_surface  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixels", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "scan.json")
    args = parser.parse_args()
    setup = build_scan(args.pixels)
    trajectory, stage, surface = setup.trajectory, setup.stage, setup.surface
    cx, cy = setup.controllers["diapi"]
    geometry = trajectory.geometry
    rng = np.random.default_rng(1)
    setup.scan()  # warm-up: compiled kernels load from numba's cache

    t_ff, (vx, vy) = timed(lambda: (cx.predict(trajectory.x), cy.predict(trajectory.y)), args.repeats)
    t_plant, (xa, ya) = timed(lambda: stage.move(trajectory.t, vx, vy), args.repeats)
    t_lookup, s = timed(lambda: surface_under_tip(surface, xa, ya), args.repeats)
    t_z, _ = timed(lambda: track_surface(s, geometry.sample_rate_hz, setup.z_stage, setup.z_feedback, rng), args.repeats)
    t_frame, images = timed(setup.scan, args.repeats)
    if not (np.all(np.isfinite(images.trace.z)) and np.all(np.isfinite(images.retrace.z))):
        raise SystemExit("scan produced non-finite heights")
    ideal = setup.scan("ideal")
    shift_x, _ = image_shift(ideal.trace.z, ideal.retrace.z, ideal.trace.pixel_size)
    if not abs(shift_x) < geometry.pixel_size[0]:
        raise SystemExit(f"ideal stage: trace/retrace shifted by {shift_x:.3g} m, more than a pixel")
    result = {
        "benchmark": f"{args.pixels}x{args.pixels} trace+retrace scan, all stage physics on, DIAPI feedforward",
        "samples": int(trajectory.t.size),
        "z_loop_steps_per_sample": int(np.ceil(setup.z_feedback.loop_rate_hz / geometry.sample_rate_hz)),
        "seconds": {"feedforward": t_ff, "xy_plant": t_plant, "surface_lookup": t_lookup, "z_loop": t_z,
                    "scan_frame_total": t_frame},
        "ideal_stage_shift_x_m": float(shift_x),
        "load_average_1_5_15_min": list(os.getloadavg()),
        "machine": machine_info(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
