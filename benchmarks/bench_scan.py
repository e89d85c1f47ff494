"""Scan-loop speed: one 256 × 256 trace+retrace frame with all stage physics on.

Times each part of one scan (controller feedforward, XY plant, surface lookup, Z loop, imaging)
and the whole ``scan_frame`` call (median of ``--repeats``), checks the frame is sane (finite,
trace and retrace of the ideal stage agree), and writes ``benchmarks/results/scan.json``.

    python benchmarks/bench_scan.py [--pixels 256] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import machine_info, median_seconds as timed  # noqa: E402
from afmsim.compensation import build_controller  # noqa: E402
from afmsim.experiment import build_sample, build_stage, identify_axes, scan_geometry  # noqa: E402
from afmsim.scan import ZFeedback, ZStage, raster_trajectory, scan_frame, track_surface  # noqa: E402
from afmsim.scan.raster import surface_under_tip  # noqa: E402
from afmsim.scenario import parse_scenario  # noqa: E402
from afmsim.tip import dilate, mlct_tip  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixels", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "scan.json")
    args = parser.parse_args()
    scenario = parse_scenario({"sample": {"kind": "microlens"}, "scan": {"size_um": [30, 30], "offset_um": [2, 2],
                               "pixels": args.pixels, "lines": args.pixels}})
    geometry = scan_geometry(scenario)
    trajectory = raster_trajectory(geometry)
    truth, _ = build_sample(scenario, geometry)
    surface = dilate(truth, mlct_tip())
    stage = build_stage(scenario)
    records = identify_axes(stage, scenario, geometry, np.random.default_rng(0))
    cx, cy = (build_controller("diapi", *records[a], nominal_sensitivity_m_per_V=stage.x.params.sensitivity_m_per_V)
              for a in ("x", "y"))
    rng = np.random.default_rng(1)
    z_stage, z_feedback = ZStage(), ZFeedback()
    scan_frame(surface, trajectory, stage, cx, cy, z_stage, z_feedback, rng)  # compile / warm caches

    t_ff, (vx, vy) = timed(lambda: (cx.predict(trajectory.x), cy.predict(trajectory.y)), args.repeats)
    t_plant, (xa, ya) = timed(lambda: stage.move(trajectory.t, vx, vy), args.repeats)
    t_lookup, s = timed(lambda: surface_under_tip(surface, xa, ya), args.repeats)
    t_z, heights = timed(lambda: track_surface(s, geometry.sample_rate_hz, z_stage, z_feedback, rng), args.repeats)
    t_frame, images = timed(lambda: scan_frame(surface, trajectory, stage, cx, cy, z_stage, z_feedback, rng), args.repeats)
    if not (np.all(np.isfinite(images.trace.z)) and np.all(np.isfinite(images.retrace.z))):
        raise SystemExit("scan produced non-finite heights")
    result = {
        "benchmark": f"{args.pixels}x{args.pixels} trace+retrace scan, all stage physics on, DIAPI feedforward",
        "samples": int(trajectory.t.size), "z_loop_steps_per_sample": int(np.ceil(z_feedback.loop_rate_hz / geometry.sample_rate_hz)),
        "seconds": {"feedforward": t_ff, "xy_plant": t_plant, "surface_lookup": t_lookup, "z_loop": t_z,
                    "scan_frame_total": t_frame},
        "machine": machine_info(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
