"""Running a scenario: the whole virtual-AFM experiment, from the scenario to images and scores.

For each of ``experiments`` repetitions (each with its own seeded random stream):

1. the identification experiment (paper §3.2) is run on both stage axes with fresh sensor noise;
2. every requested controller is identified from it (``none``/``ideal`` need no data);
3. each controller scans the tip-dilated sample through the stage plant (``ideal``: through the
   memory-free twin of the stage, :func:`ideal_twin`) with a fresh Z-loop noise stream;
4. trace and retrace are scored: binarized NSL2 (eq. 8), sub-pixel shift, and for micro-lenses the
   centre shift, for gratings the left/right line pitch.

The sample is placed in stage coordinates centred on the scan window and built on a grid that
covers the window plus a margin for the stage's excursions, ``sample_oversampling`` times finer
than the image pixels.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from afmsim.compensation import build_controller
from afmsim.metrics import image_shift, lens_centres, left_right_pitch, nsl2_binarized, scale_x, summarize
from afmsim.metrics.nsl2 import e_D
from afmsim.reproducible import single_blas_thread
from afmsim.samples import HeightMap, MicroLensArray, grating_heightmap, load_heightmap, mesh_file_to_heightmap
from afmsim.scan import RasterGeometry, ScanImages, ZFeedback, ZStage, raster_trajectory, scan_frame
from afmsim.scenario import Scenario
from afmsim.stage import XYStage, default_stage, triangle_wave
from afmsim.tip import dilate, mlct_tip
from afmsim.workers import ordered_map, shared, worker_pool

__all__ = ["ScenarioResult", "run_scenario", "build_stage", "build_sample", "scan_geometry", "identify_axes", "ideal_twin"]

UM, NM = 1e-6, 1e-9


def build_stage(scenario: Scenario) -> XYStage:
    """The XY plant with the scenario's physics switches; a calibrated twin's stage when ``instrument:`` is set."""
    s = scenario.stage
    switches = dict(saturation=s.saturation, amplifier=s.amplifier, creep=s.creep, drift=s.drift,
                    resonance=s.dynamics, noise=s.sensor_noise, coupling=s.cross_coupling > 0)
    if scenario.instrument is not None:
        from afmsim.twin import build_twin_stage, load_instrument

        return build_twin_stage(load_instrument(scenario.instrument)).with_effects(**switches)
    stage = default_stage(s.hysteresis).with_effects(**switches)
    return replace(stage, coupling_x_to_y=s.cross_coupling, coupling_y_to_x=s.cross_coupling)


def ideal_twin(stage: XYStage) -> XYStage:
    """The stage of the ``ideal`` controller: no piezo memory (hysteresis *and* creep), all else equal.

    Creep is removed too because at line rates its fast relaxation components act as a small
    rate-dependent hysteresis (≈ γ × scan size, 0.5 µm on a 30 µm scan at γ = 1.5 %/decade) that the
    inverse models, identified at the same rate, partly compensate: a stage that kept it would not
    be a floor. Drift, dynamics, cross-coupling, saturation and noise stay as in ``stage``.
    """
    return stage.with_effects(hysteresis=False, creep=False)


def scan_geometry(scenario: Scenario) -> RasterGeometry:
    """The raster geometry in SI units."""
    s, n = scenario.scan, scenario.numerics
    return RasterGeometry(size=(s.size_um[0] * UM, s.size_um[1] * UM), offset=(s.offset_um[0] * UM, s.offset_um[1] * UM),
                          pixels=s.pixels, lines=s.lines, line_rate_hz=s.line_rate_hz,
                          samples_per_pixel=n.samples_per_pixel, approach_s=n.approach_s)


def _sample_grid(geometry: RasterGeometry, oversampling: int):
    """Grid (shape, pixel size, centre) covering the scan window plus a margin, stage coordinates."""
    w, h = geometry.size
    margin = 0.25 * max(w, h) + 2 * UM
    pixel = min(geometry.pixel_size) / oversampling
    shape = (int(np.ceil((h + 2 * margin) / pixel)), int(np.ceil((w + 2 * margin) / pixel)))
    centre = (geometry.offset[0] + w / 2, geometry.offset[1] + h / 2)
    return shape, (pixel, pixel), centre


def build_sample(scenario: Scenario, geometry: RasterGeometry):
    """True topography on the simulation grid, and the sample mesh when there is one.

    Returns ``(HeightMap, trimesh.Trimesh | None)``; the micro-lens array is centred on the scan
    window with a lens at the centre.
    """
    spec = scenario.sample
    shape, pixel, centre = _sample_grid(geometry, scenario.numerics.sample_oversampling)
    extent = (shape[1] * pixel[0], shape[0] * pixel[1])
    if spec.kind == "microlens":
        counts = tuple(int(np.ceil(e / (spec.pitch_um * UM))) // 2 * 2 + 1 for e in extent)
        lenses = MicroLensArray(diameter=spec.diameter_um * UM, sag=spec.sag_um * UM, pitch=spec.pitch_um * UM,
                                arrangement=spec.arrangement, n_lenses=counts, center=centre)
        mesh = lenses.mesh()
        return lenses.heightmap(shape, extent, center=centre, mesh=mesh), mesh
    if spec.kind == "grating":
        return grating_heightmap(shape, extent, center=centre, period=spec.period_um * UM, height=spec.step_nm * NM,
                                 duty_cycle=spec.duty_cycle, sidewall_angle_deg=spec.sidewall_deg), None
    if spec.kind == "mesh":
        return mesh_file_to_heightmap(spec.path, shape, extent, unit=spec.unit_m, center=centre), None
    loaded = load_heightmap(spec.path, spec.pixel_size_nm * NM, z_scale=spec.z_unit_m)
    origin = (centre[0] - loaded.size[0] / 2, centre[1] - loaded.size[1] / 2)
    return HeightMap(loaded.z, loaded.pixel_size, origin), None


def identify_axes(stage: XYStage, scenario: Scenario, geometry: RasterGeometry, rng: np.random.Generator):
    """Identification records ``{"x": (displacement, voltage), "y": (...)}`` for one experiment.

    Each axis is driven alone by the triangle (paper §3.2) from rest and read by its sensor; the
    first cycle is returned. With ``identification.range: scan`` the amplitude is reduced so the
    loop just covers the scan's own range on that axis.
    """
    ident = scenario.identification
    records = {}
    for axis, far_edge in (("x", geometry.offset[0] + geometry.size[0]), ("y", geometry.offset[1] + geometry.size[1])):
        amplitude = ident.amplitude_V
        if ident.range == "scan":
            amplitude = min(amplitude, 1.05 * far_edge / getattr(stage, axis).params.sensitivity_m_per_V)
        t, v = triangle_wave(amplitude, ident.frequency_hz, ident.sample_rate_hz, cycles=1)
        zero = np.zeros_like(v)
        x, y = stage.move(t, v, zero) if axis == "x" else stage.move(t, zero, v)
        measured = getattr(stage, axis).measure(x if axis == "x" else y, rng)
        records[axis] = (measured, v)
    return records


@dataclass
class ScenarioResult:
    """Everything a run produces: per-controller images of the first experiment and all scores."""

    scenario: Scenario
    truth: HeightMap
    dilated: HeightMap
    mesh: object
    images: dict = field(default_factory=dict)      # controller -> ScanImages (experiment 1)
    frames: list = field(default_factory=list)      # per experiment: controller -> (trace, retrace) HeightMaps
    scores: dict = field(default_factory=dict)      # controller -> metric -> list over experiments
    notes: list = field(default_factory=list)       # scores that could not be measured, and why
    timings: dict = field(default_factory=dict)     # wall times (s) of the stages, and the worker count

    def metrics(self) -> dict:
        """The ``metrics.json`` content: mean/std/per-experiment of every score, and e_D."""
        controllers = {name: {metric: summarize(values) for metric, values in per.items()}
                       for name, per in self.scores.items()}
        out = {"controllers": controllers,
               "units": {"nsl2": "1", "shift_x_m": "m", "shift_y_m": "m", "saturated_fraction": "1"}}
        if "spi" in controllers and "diapi" in controllers:
            out["e_D"] = float(e_D(controllers["spi"]["nsl2"]["mean"], controllers["diapi"]["nsl2"]["mean"]))
        if "ideal" in controllers:
            floor = controllers["ideal"]["nsl2"]["mean"]
            out["nsl2_over_ideal"] = {n: c["nsl2"]["mean"] / floor if floor > 0 else None for n, c in controllers.items()}
        notes = list(self.notes)
        saturated = {n: c["saturated_fraction"]["mean"] for n, c in controllers.items()
                     if c.get("saturated_fraction", {}).get("mean", 0) > 0}
        if saturated:
            notes.append("a drive sat at its amplifier limit (stage or Z travel exceeded; the image is flat there) in "
                         + ", ".join(f"{n} {f:.2%}" for n, f in saturated.items())
                         + " of the scan's samples (saturated_fraction, mean over experiments)")
        if notes:
            out["notes"] = notes
        return out


def _score(images: ScanImages, kind: str) -> tuple[dict, list[str]]:
    """Scores of one trace/retrace pair, and notes on scores that could not be measured."""
    trace, retrace = images.trace, images.retrace
    notes = []
    shift_x, shift_y = image_shift(trace.z, retrace.z, trace.pixel_size)
    scores = {"nsl2": nsl2_binarized(trace.z, retrace.z), "shift_x_m": shift_x, "shift_y_m": shift_y,
              "saturated_fraction": images.saturated_fraction}
    scores["scale_x"] = scale_x(trace.x, images.actual_x_trace, images.actual_x_retrace)
    if kind == "microlens":
        centre_shift = _central_lens_shift(trace, retrace)
        if centre_shift is not None:
            scores["lens_centre_shift_x_m"] = centre_shift
    if kind == "grating":
        for label, image in (("trace", trace), ("retrace", retrace)):
            try:
                left, right = left_right_pitch(image.z, image.pixel_size)
            except ValueError as error:  # a half field without a complete period: the other scores stand
                notes.append(f"{label}_pitch_left_m/_right_m not measured: {error} (a scan about 2.5 grating "
                             f"periods wide or more has a complete period in each half)")
                continue
            scores[f"{label}_pitch_left_m"], scores[f"{label}_pitch_right_m"] = left, right
    return scores, notes


def _central_lens_shift(trace: HeightMap, retrace: HeightMap):
    """x shift (m) of the lens nearest the image centre between trace and retrace, or None."""
    found = []
    for image in (trace, retrace):
        centres = lens_centres(image.z, image.pixel_size, origin=image.origin)
        if len(centres) == 0:
            return None
        middle = np.array([image.x.mean(), image.y.mean()])
        found.append(centres[np.argmin(np.linalg.norm(centres - middle, axis=1))])
    return float(found[1][0] - found[0][0])


def _scan_one(name: str, records: dict, rng: np.random.Generator) -> ScanImages:
    """One controller's scan of one experiment: fit the controller to the experiment's identification
    ``records``, then scan (the shared inputs come from :func:`afmsim.workers.shared`)."""
    scenario, stage = shared("scenario"), shared("stage")
    controllers = [build_controller(name, *records[axis], n_operators=scenario.identification.n_operators,
                                    nominal_sensitivity_m_per_V=getattr(stage, axis).params.sensitivity_m_per_V)
                   for axis in ("x", "y")]
    plant = ideal_twin(stage) if name == "ideal" else stage
    images = scan_frame(shared("dilated"), shared("trajectory"), plant, *controllers, shared("z_stage"),
                        shared("z_feedback"), rng)
    # Own, C-contiguous arrays: the scores of a strided view and of its (pickled) copy differ in
    # the last bits (numpy sums them in another order), so serial and parallel runs score copies.
    return replace(images, trace=replace(images.trace, z=np.ascontiguousarray(images.trace.z)),
                   retrace=replace(images.retrace, z=np.ascontiguousarray(images.retrace.z)),
                   actual_x_trace=np.ascontiguousarray(images.actual_x_trace),
                   actual_x_retrace=np.ascontiguousarray(images.actual_x_retrace))


@single_blas_thread
def run_scenario(scenario: Scenario, progress=None, *, workers: int = 1) -> ScenarioResult:
    """Run every experiment of a scenario.

    ``progress(stage, done, total)`` is called if given, ``stage`` one of "sample" (building and
    tip-dilating it), "identify", "scan", "metrics". The scans (experiments × controllers) and
    their scores run on ``workers`` forked processes (:mod:`afmsim.workers`); the result is
    bit-identical for any ``workers``. The identification of each experiment is run once and
    shared by its controllers. The wall times of the stages are in ``result.timings`` (s).
    """
    started = time.perf_counter()
    if progress is not None:
        progress("sample", 0, 1)
    geometry = scan_geometry(scenario)
    trajectory = raster_trajectory(geometry)
    truth, mesh = build_sample(scenario, geometry)
    tip = mlct_tip(scenario.tip.shape, scenario.tip.apex_radius_nm * NM, scenario.tip.half_angle_deg)
    dilated = dilate(truth, tip)
    if progress is not None:
        progress("sample", 1, 1)
    stage = build_stage(scenario)
    z_stage = ZStage(sensitivity_m_per_V=scenario.z_stage.sensitivity_um_per_V * UM,
                     max_voltage_V=scenario.z_stage.travel_um / scenario.z_stage.sensitivity_um_per_V,
                     hysteresis=scenario.z_stage.hysteresis)
    zf = scenario.z_feedback
    z_feedback = ZFeedback(ki_per_s=zf.ki_per_s, kp=zf.kp, setpoint_m=zf.setpoint_nm * NM,
                           deflection_noise_m=zf.deflection_noise_nm * NM, loop_rate_hz=scenario.numerics.z_loop_rate_hz)
    result = ScenarioResult(scenario, truth, dilated, mesh)
    names = list(dict.fromkeys(scenario.controllers))
    report = (lambda stage_name: (lambda _, done, total: progress(stage_name, done, total))) if progress else \
        (lambda stage_name: None)
    tasks = []
    for k, rng in enumerate(np.random.default_rng(scenario.seed).spawn(scenario.experiments)):
        ident_rng, *scan_rngs = rng.spawn(1 + len(names))
        records = identify_axes(stage, scenario, geometry, ident_rng)
        tasks += [(k, name, records, scan_rng) for name, scan_rng in zip(names, scan_rngs)]
        if progress is not None:
            progress("identify", k + 1, scenario.experiments)
    workers = max(1, min(int(workers), len(tasks)))
    with worker_pool(workers, scenario=scenario, stage=stage, dilated=dilated, trajectory=trajectory,
                     z_stage=z_stage, z_feedback=z_feedback) as executor:
        scans = ordered_map(executor, _scan_one, [task[1:] for task in tasks], report("scan"))
        scanned = time.perf_counter()
        scored = ordered_map(executor, _score, [(images, scenario.sample.kind) for images in scans],
                             report("metrics"))
    for (k, name, *_), images, (scores, notes) in zip(tasks, scans, scored):
        if k == 0:
            result.images[name] = images
        if k == len(result.frames):
            result.frames.append({})
        result.frames[k][name] = (images.trace, images.retrace)
        for metric, value in scores.items():
            result.scores.setdefault(name, {}).setdefault(metric, []).append(float(value))
        result.notes.extend(note for note in notes if note not in result.notes)
    result.timings = {"simulate_s": scanned - started, "metrics_s": time.perf_counter() - scanned, "workers": workers}
    return result
