"""``afmsim calibrate`` and ``afmsim predict`` as Python calls: measured file in, run folder out.

    from afmsim.twin import calibrate, predict
    calibrate("circles.nid", "twin/")                               # twin/instrument.yaml, calibration.json, figure
    predict("twin/instrument.yaml", "squares_holes.nid", "pred/")   # pred/prediction.json, figure

A ``.csv`` file is a loop record (``t_s,v_V,x_m[,y_m]``, :mod:`afmsim.twin.calibrate_loops`); any other
file is an image pair read by :mod:`afmsim.readers`. Every error is a ``ValueError`` with one line,
raised before anything is written; output goes through :func:`afmsim.runio.run_folder` (atomic,
with a manifest).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from afmsim.runio import run_folder, write_json

from .calibrate_images import FITTED, calibrate_images
from .calibrate_loops import calibrate_loop, predict_loop
from .figures import loop_figure, pair_figure
from .instrument import Instrument, InstrumentError, ScanHabitSpec, dump_instrument, load_instrument
from .measured import load_measured_pair
from .predict_images import predict_images

__all__ = ["calibrate", "predict", "pitch_from_scenario"]


def _is_loop_record(path) -> bool:
    """A file no AFM image reader claims is a loop record (``.csv``, ``.txt``, ``.tsv``…), as in ``diagnose``."""
    from afmsim.readers import reader_for

    return reader_for(path) is None


def pitch_from_scenario(path) -> float:
    """The lateral period (m) of a scenario's sample: a grating's ``period_um`` or a lens array's ``pitch_um``."""
    from afmsim.scenario import ScenarioError, load_scenario

    try:
        sample = load_scenario(path).sample
    except ScenarioError as error:
        raise ValueError(str(error)) from None
    for field in ("period_um", "pitch_um"):
        if hasattr(sample, field):
            return float(getattr(sample, field)) * 1e-6
    raise ValueError(f"--scenario {path}: sample kind {sample.kind!r} has no period; use a grating or micro-lens "
                     f"scenario, or --pitch-um")


def _provenance(fitted: list[str], header: list[str]) -> dict:
    out = {key: "fitted" for key in fitted}
    out.update({key: "header" for key in header})
    for block in ("fast_axis", "slow_axis", "z_loop", "scan"):
        for name in type(getattr(Instrument(), block)).model_fields:
            out.setdefault(f"{block}.{name}", "default")
    out.setdefault("cross_coupling", "default")
    return out


def calibrate(measured, out, *, pitch_m: float | None = None, scenario=None, channel: str | None = None,
              line_time_s: float | None = None, seed: int = 0, retrace=None) -> dict:
    """Calibrate a twin from ``measured`` and write ``out`` (see the module docstring); returns calibration.json.
    ``retrace``: a second image file with the other scan direction (Park writes one direction per file)."""
    if pitch_m is not None and scenario is not None:
        raise ValueError("give --pitch-um or --scenario, not both")
    if pitch_m is not None and not (0 < pitch_m < 1e-3):
        raise ValueError(f"--pitch-um must be in (0, 1000) µm, got {pitch_m * 1e6:g}")
    if (pitch_m is not None or scenario is not None) and _is_loop_record(measured):
        raise ValueError("--pitch-um/--scenario apply to image pairs, not to a loop record")
    if retrace is not None and _is_loop_record(measured):
        raise ValueError("--retrace goes with an image file, not with a loop record")
    if scenario is not None:
        pitch_m = pitch_from_scenario(scenario)
    out = Path(out)
    if out.exists():
        raise ValueError(f"output folder {out} already exists: choose another --out or remove it")
    name = Path(measured).stem
    if _is_loop_record(measured):
        loop = calibrate_loop(measured)
        instrument = loop.instrument.model_copy(update={"name": name, "calibrated_from": str(measured),
                                                        "provenance": _provenance(loop.fitted, [])})
        report, arrays = loop.report, None
    else:
        pair = load_measured_pair(measured, channel, line_time_s, retrace)
        header = []
        start = Instrument(name=name, calibrated_from=str(measured))
        # a scan wider than afmsim's 100 µm travel gets a travel with 30 % to spare (not constrained)
        needed_um = 1.3 * pair.scan.size_m[0] * (1 + (pair.overscan_fraction or 0.0)) * 1e6
        if needed_um > start.fast_axis.travel_um:
            start = start.model_copy(update={"fast_axis": start.fast_axis.model_copy(update={"travel_um": needed_um}),
                                             "slow_axis": start.slow_axis.model_copy(update={"travel_um": needed_um})})
        if pair.overscan_fraction is not None:
            start = start.model_copy(update={"scan": ScanHabitSpec(overscan_fraction=min(pair.overscan_fraction, 1.0))})
            header.append("scan.overscan_fraction")
        cal = calibrate_images(pair.trace, pair.retrace, pair.scan, start=start, pitch_m=pitch_m)
        instrument = cal.instrument.model_copy(update={
            "provenance": _provenance([*FITTED, "z_loop.height_noise_nm"], header)})
        report, arrays = _image_report(cal, pair, instrument, seed)
    report["not_constrained"] = sorted(k for k, v in instrument.provenance.items() if v == "default")
    config = {"measured": str(measured), **({"retrace": str(retrace)} if retrace is not None else {}),
              "pitch_m": pitch_m, "scenario": str(scenario) if scenario else None,
              "channel": channel, "line_time_s": line_time_s}
    with run_folder(out, config=config, seed=seed, command="calibrate") as folder:
        dump_instrument(instrument, folder / "instrument.yaml")
        write_json(folder / "calibration.json", report)
        if arrays is None:
            loop_figure(folder / "calibration.png", *loop.figure_data, title=f"{name}: loop record")
        else:
            pair_figure(folder / "calibration.png", arrays, pair.scan.size_m[0] / pair.scan.pixels,
                        f"{name}: measured vs twin (held-out odd lines)")
    return report


def _image_report(cal, pair, instrument: Instrument, seed: int) -> tuple[dict, dict]:
    """calibration.json for an image pair and the figure's arrays; the held-out fit is the full twin
    scan of the odd lines."""
    from .raster import RealScan

    odd = slice(1, None, 2)
    scan_odd = RealScan(pair.scan.size_m, pair.scan.pixels, int(pair.trace[odd].shape[0]), pair.scan.line_time_s)
    held, arrays = predict_images(instrument, pair.trace[odd], pair.retrace[odd], scan_odd, seed=seed)
    parameters = {key: {"value": cal.values[key], "uncertainty": cal.uncertainties[key], "provenance": "fitted"}
                  for key in FITTED}
    parameters["z_loop.height_noise_nm"] = {"value": instrument.z_loop.height_noise_nm, "uncertainty": None,
                                            "provenance": "fitted"}
    return {
        "measured": str(pair.path), "picked": pair.picked,
        "scan": {"size_m": pair.scan.size_m, "pixels": pair.scan.pixels, "lines": pair.scan.lines,
                 "line_time_s": pair.scan.line_time_s, "overscan_fraction": pair.overscan_fraction},
        "parameters": parameters,
        "parameter_correlation": {"order": list(FITTED), "matrix": cal.correlation},
        "fit": {"lines": "up to 64 of the even lines (0, 2, 4, ...), evenly spread", "windows": int(cal.measured_profile.x_m.size),
                "train_profile_rms_error_m": cal.train_profile_rms_error_m, **cal.facts},
        "held_out": {"lines": "odd lines (1, 3, 5, ...), full twin scan", "x_m": held["x_m"],
                     "measured_shift_m": held["measured_shift_m"], "twin_shift_m": held["predicted_shift_m"],
                     "rms_error_m": held["rms_error_m"], "measured_rms_m": held["measured_rms_m"],
                     "nsl2": held["nsl2"], "default_stage": held["default_stage"]},
    }, arrays


def predict(instrument_path, measured, out, *, channel: str | None = None, line_time_s: float | None = None,
            seed: int = 0, retrace=None) -> dict:
    """Predict ``measured`` on the twin in ``instrument_path``; write ``out``; returns prediction.json.
    ``retrace``: a second image file with the other scan direction (Park writes one direction per file)."""
    try:
        instrument = load_instrument(instrument_path)
    except InstrumentError as error:
        raise ValueError(str(error)) from None
    out = Path(out)
    if out.exists():
        raise ValueError(f"output folder {out} already exists: choose another --out or remove it")
    config = {"instrument": str(instrument_path), "measured": str(measured), "channel": channel,
              "line_time_s": line_time_s, **({"retrace": str(retrace)} if retrace is not None else {})}
    if retrace is not None and _is_loop_record(measured):
        raise ValueError("--retrace goes with an image file, not with a loop record")
    if _is_loop_record(measured):
        prediction, figure_data = predict_loop(instrument, measured)
        with run_folder(out, config=config, seed=seed, command="predict") as folder:
            write_json(folder / "prediction.json", prediction)
            loop_figure(folder / "prediction.png", *figure_data, title=f"{Path(measured).stem}: held-out prediction")
        return prediction
    pair = load_measured_pair(measured, channel, line_time_s, retrace)
    prediction, arrays = predict_images(instrument, pair.trace, pair.retrace, pair.scan, seed=seed)
    prediction = {"instrument": str(instrument_path), "measured": str(pair.path), "picked": pair.picked, **prediction}
    with run_folder(out, config=config, seed=seed, command="predict") as folder:
        write_json(folder / "prediction.json", prediction)
        pair_figure(folder / "prediction.png", arrays, pair.scan.size_m[0] / pair.scan.pixels,
                    f"{Path(measured).stem}: measured vs twin")
    return prediction
