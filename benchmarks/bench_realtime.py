"""Real-time factor of the scan loop: one 512 × 512 trace+retrace frame at 1 Hz, all physics on, one core.

The scenario is ``scenarios/microlens.yaml`` at 512 × 512 px: the Preisach stage with every effect
on (saturation, amplifier, creep, drift, resonance, cross-coupling), DIAPI feedforward on both
axes, the hysteretic Z stage under the PI loop at ``numerics.z_loop_rate_hz`` (50 kHz) and
``numerics.samples_per_pixel`` (4). Instrument time is the trajectory's duration (approach +
lines / line rate: 513 s); the real-time factor is instrument time ÷ the median wall time of
``--repeats`` ``scan_frame`` calls after one warm-up call (also given on the process's CPU time,
which other work on a shared machine inflates less). Every thread pool is limited to one thread
before numpy/numba load. Checks: the frame is finite, and on the memory-free stage
(``ideal`` controller) trace and retrace agree. Writes ``benchmarks/results/realtime.json`` with
machine information and the load average (the machine may be shared; the file says so).

    python benchmarks/bench_realtime.py [--pixels 512] [--repeats 3]
"""

from __future__ import annotations

import os

for _var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _timing import machine_info  # noqa: E402
from afmsim.compensation import build_controller  # noqa: E402
from afmsim.experiment import build_sample, build_stage, identify_axes, ideal_twin, scan_geometry  # noqa: E402
from afmsim.metrics import image_shift  # noqa: E402
from afmsim.scan import ZFeedback, ZStage, raster_trajectory, scan_frame  # noqa: E402
from afmsim.scenario import parse_scenario  # noqa: E402
from afmsim.tip import dilate, mlct_tip  # noqa: E402

UM, NM = 1e-6, 1e-9
SCENARIO = ROOT / "scenarios" / "microlens.yaml"
TARGET_FACTOR = 1000.0


@dataclass
class ScanSetup:
    """Everything one ``scan_frame`` call needs, built once (sample, stage, identified controllers)."""

    scenario: object
    trajectory: object
    surface: object
    stage: object
    controllers: dict
    z_stage: ZStage
    z_feedback: ZFeedback

    @property
    def instrument_time_s(self) -> float:
        """Duration of the trajectory (approach + frame), seconds."""
        return self.trajectory.t.size / self.trajectory.geometry.sample_rate_hz

    def scan(self, controller: str = "diapi", seed: int = 1):
        """One frame with ``controller`` (``ideal``: through the memory-free twin of the stage)."""
        plant = ideal_twin(self.stage) if controller == "ideal" else self.stage
        return scan_frame(self.surface, self.trajectory, plant, *self.controllers[controller], self.z_stage,
                          self.z_feedback, np.random.default_rng(seed))


def build_scan(pixels: int) -> ScanSetup:
    """The micro-lens scenario at ``pixels`` × ``pixels``, 1 Hz line rate, DIAPI and ideal controllers."""
    data = yaml.safe_load(SCENARIO.read_text())
    data["scan"].update(pixels=pixels, lines=pixels, line_rate_hz=1.0)
    scenario = parse_scenario(data)
    geometry = scan_geometry(scenario)
    truth, _ = build_sample(scenario, geometry)
    tip = scenario.tip
    surface = dilate(truth, mlct_tip(tip.shape, tip.apex_radius_nm * NM, tip.half_angle_deg))
    stage = build_stage(scenario)
    records = identify_axes(stage, scenario, geometry, np.random.default_rng(0))
    controllers = {name: [build_controller(name, *records[axis], n_operators=scenario.identification.n_operators,
                                           nominal_sensitivity_m_per_V=getattr(stage, axis).params.sensitivity_m_per_V)
                          for axis in ("x", "y")] for name in ("diapi", "ideal")}
    z, zf = scenario.z_stage, scenario.z_feedback
    z_stage = ZStage(sensitivity_m_per_V=z.sensitivity_um_per_V * UM, max_voltage_V=z.travel_um / z.sensitivity_um_per_V,
                     hysteresis=z.hysteresis)
    z_feedback = ZFeedback(ki_per_s=zf.ki_per_s, kp=zf.kp, setpoint_m=zf.setpoint_nm * NM,
                           deflection_noise_m=zf.deflection_noise_nm * NM, loop_rate_hz=scenario.numerics.z_loop_rate_hz)
    return ScanSetup(scenario, raster_trajectory(geometry), surface, stage, controllers, z_stage, z_feedback)


def load_note(load: float) -> str:
    """A warning for the results file when other work shared the CPUs (1-minute load average > 1)."""
    if load > 1.0:
        return (f"shared machine: 1-minute load average up to {load:.2f} on {os.cpu_count()} CPUs while measuring; "
                f"wall times are likely longer than on an idle machine")
    return "machine idle enough (1-minute load average <= 1)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixels", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "realtime.json")
    args = parser.parse_args()
    setup = build_scan(args.pixels)
    g = setup.trajectory.geometry
    load_before = os.getloadavg()
    setup.scan()                                   # warm-up: compiled kernels load from numba's cache
    walls, cpus = [], []
    for _ in range(args.repeats):
        wall_start, cpu_start = time.perf_counter(), time.process_time()
        images = setup.scan()
        walls.append(time.perf_counter() - wall_start)
        cpus.append(time.process_time() - cpu_start)
    wall, cpu = statistics.median(walls), statistics.median(cpus)
    load_after = os.getloadavg()

    finite = bool(np.all(np.isfinite(images.trace.z)) and np.all(np.isfinite(images.retrace.z)))
    ideal = setup.scan("ideal")
    shift_x, _ = image_shift(ideal.trace.z, ideal.retrace.z, ideal.trace.pixel_size)
    mismatch = float(np.sqrt(np.mean((ideal.trace.z - ideal.retrace.z) ** 2)) / np.ptp(ideal.trace.z))
    agree = bool(abs(shift_x) < g.pixel_size[0] and mismatch < 0.02)
    factor = setup.instrument_time_s / wall
    load = max(load_before[0], load_after[0])
    result = {
        "benchmark": f"{g.pixels}x{g.lines} trace+retrace scan at {g.line_rate_hz:g} Hz line rate, all physics on, "
                     "DIAPI feedforward, one thread",
        "scenario": str(SCENARIO.relative_to(ROOT)),
        "samples": int(setup.trajectory.t.size),
        "z_loop_rate_hz": setup.z_feedback.loop_rate_hz,
        "samples_per_pixel": g.samples_per_pixel,
        "instrument_time_s": setup.instrument_time_s,
        "wall_s_median": wall,
        "wall_s_each": walls,
        "cpu_s_median": cpu,
        "repeats": args.repeats,
        "real_time_factor": factor,
        "real_time_factor_on_cpu_time": setup.instrument_time_s / cpu,
        "target_real_time_factor": TARGET_FACTOR,
        "meets_target": bool(factor >= TARGET_FACTOR),
        "checks": {"finite": finite, "ideal_stage_trace_retrace_agree": agree, "ideal_shift_x_m": float(shift_x),
                   "ideal_rms_trace_minus_retrace_over_range": mismatch},
        "threads": {var: os.environ[var] for var in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                                                     "OPENBLAS_NUM_THREADS")},
        "load_average_1_5_15_min": {"before": list(load_before), "after": list(load_after)},
        "load_note": load_note(load),
        "machine": machine_info(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    if not (finite and agree):
        raise SystemExit("scan check failed: non-finite heights or ideal-stage trace/retrace disagree")


if __name__ == "__main__":
    main()
