"""Writing a scenario run into its folder: images, raw arrays, metrics, figures, renders, report."""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

import numpy as np
import yaml

from afmsim.experiment import ScenarioResult
from afmsim.runio import git_revision, versions, write_json
from afmsim.samples.heightmap import HeightMap
from afmsim.workers import ordered_map, worker_pool

from .document import best_controller, write_report
from .figures import run_colour_scales
from .gwy import write_gwy
from .paper_figures import plot_binarized, plot_scan_figures
from .render_process import RenderProcess, start_renders
from .renders import render_jobs, render_names
from .tables import nsl2_markdown, write_nsl2_table

__all__ = ["write_run", "gwy_channels", "RENDER_CHOICES"]

#: ``renders=`` of :func:`write_run`: no 3D renders, the key ones (sample, ``none`` and the best
#: controller's trace), or all (every controller's trace and retrace, and the sample).
RENDER_CHOICES = ("none", "key", "all")


def gwy_channels(frames: list, truth, errors: dict | None = None) -> dict:
    """The ``images.gwy`` channels: "trace <c>", "retrace <c>" per controller of experiment 1, the
    same with " (experiment k)" for the other experiments, "topography", then experiment 1's
    deflection (error) images "error trace <c>", "error retrace <c>" from ``errors`` (controller →
    (trace, retrace) HeightMaps, m; after the rest, so the other channels keep their numbers)."""
    channels = {}
    for k, images in enumerate(frames, 1):
        suffix = "" if k == 1 else f" (experiment {k})"
        for name, (trace, retrace) in images.items():
            channels[f"trace {name}{suffix}"] = trace
            channels[f"retrace {name}{suffix}"] = retrace
    channels["topography"] = truth
    for name, (trace, retrace) in (errors or {}).items():
        channels[f"error trace {name}"] = trace
        channels[f"error retrace {name}"] = retrace
    return channels


def write_run(result: ScenarioResult, folder, *, renders: str = "key", progress=None, workers: int = 1,
              render_process: RenderProcess | None = None) -> list[Path]:
    """Write a run's files into ``folder`` and return their paths.

    ``metrics.json``, ``scenario.yaml``, ``images.npz``, ``images.gwy`` (every experiment, with the
    line rate and the scenario in each channel's metadata), per controller ``figure_<c>.png``
    (trace, retrace, trace − retrace, cross-section and zoom: the Fig. 10–13 analogue),
    ``binarized.png``, ``nsl2_table.md/.csv`` (Table 3/4 analogue), 3D ``render_*.png`` as chosen
    by ``renders`` (:data:`RENDER_CHOICES`; skipped with a warning in the report where this machine
    cannot render), ``report.html`` (self-contained) and ``report.md``.

    Figures are drawn on ``workers`` forked processes (:mod:`afmsim.workers`), the renders beside
    them in one forked process of their own: ``render_process`` when given (a
    :class:`~afmsim.report.render_process.RenderProcess` started before the simulation has its
    start-up cost paid already; it is used or closed here), else a fresh one. ``progress(stage,
    done, total)`` hears of the "figures", "renders" and "report" stages.

    ``images.npz`` holds ``trace_<controller>``/``retrace_<controller>`` of experiment 1 (heights in
    metres, rows = lines, columns = pixels left → right), ``error_trace_<controller>``/
    ``error_retrace_<controller>`` (the Z loop's error signal, deflection less setpoint, m: the
    deflection images an AFM records), ``truth`` and ``dilated`` (the sample and the surface the tip
    sees, on the simulation grid), and the grids' ``*_pixel_size_m``/``*_origin_m``.
    """
    if renders not in RENDER_CHOICES:
        raise ValueError(f"renders must be one of {', '.join(RENDER_CHOICES)}, got {renders!r}")
    started = time.perf_counter()
    folder = Path(folder)
    scenario, kind = result.scenario, result.scenario.sample.kind
    metrics = result.metrics()
    write_json(folder / "metrics.json", metrics)
    scenario_yaml = yaml.safe_dump(scenario.model_dump(mode="json"), sort_keys=False, allow_unicode=True)
    (folder / "scenario.yaml").write_text(scenario_yaml)
    pairs = {name: (im.trace, im.retrace) for name, im in result.images.items()}
    best = best_controller(metrics)
    scale = run_colour_scales(pairs) if pairs else None
    # one job per worker, each redrawing one figure for its share of the controllers (a redraw costs
    # about half a first draw), then the binarized overview
    names = list(pairs)
    shares = [names[k::max(1, workers)] for k in range(min(max(1, workers), len(names)))]
    figure_jobs = [(plot_scan_figures, ({name: pairs[name] for name in share}, folder),
                    {"kind": kind, "title": f"{scenario.name}: controller '{{controller}}' (experiment 1)",
                     "scale": scale}) for share in shares]
    if pairs:
        figure_jobs.append((plot_binarized, (pairs, folder / "binarized.png"),
                            {"title": f"{scenario.name}: binarized images used for NSL2 (experiment 1)"}))
    written, warnings = [folder / "metrics.json", folder / "scenario.yaml"], []
    render_files = [] if renders == "none" else [folder / n for n in render_names(list(pairs), renders, best)]
    if progress is not None and render_files:
        progress("renders", 0, len(render_files))
    draw = partial(_draw_renders, pairs, result.truth, result.mesh, folder, scenario.name, renders, best)
    if render_process is None:
        renders_done = start_renders(draw, render_files)
    elif render_files:
        renders_done = render_process.submit(draw, render_files)
    else:
        render_process.close()
        renders_done = start_renders(draw, [])
    try:
        with worker_pool(max(1, workers)) as executor:
            figures = ordered_map(executor, _call, figure_jobs,
                                  _files_ticker(progress, "figures", [len(share) for share in shares] + [1]), wait=False)
            written += _write_arrays(result, folder, scenario_yaml)
            done = figures()  # a list of paths per share, then the binarized overview's path
            figure_paths = [path for share in done[:len(shares)] for path in share] + done[len(shares):]
    finally:  # the render process is waited for even when a figure fails: nothing writes after we return
        render_paths, warning = renders_done()
    if warning:
        warnings.append(warning)
    elif progress is not None and render_files:
        progress("renders", len(render_files), len(render_files))
    written += figure_paths + render_paths
    if progress is not None:
        progress("report", 0, 1)
    table, table_paths = write_nsl2_table(metrics, kind, folder)
    written += table_paths
    provenance = {"afmsim": versions()["afmsim"], **git_revision(), "date_utc": time.strftime("%Y-%m-%d %H:%M UTC"),
                  **result.timings, "figures_s": time.perf_counter() - started}
    written += write_report(folder, result=result, metrics=metrics, nsl2_md=nsl2_markdown(table),
                            scenario_yaml=scenario_yaml, figures=figure_paths, renders=render_paths,
                            renders_choice=renders, best=best, warnings=warnings, provenance=provenance)
    if progress is not None:
        progress("report", 1, 1)
    return written


def _call(func, args, kwargs):
    return func(*args, **kwargs)


def _draw_renders(pairs, truth, mesh, folder, name, which, best) -> list[Path]:
    """The run's renders (:func:`afmsim.report.renders.render_jobs`), one after the other: VTK's
    first-render set-up (EGL context, shaders; about two renders' worth) is paid once."""
    return [func(*args) for func, args in render_jobs(pairs, truth, mesh, folder, name=name, which=which, best=best)]


def _files_ticker(progress, stage: str, sizes: list[int]):
    """The ``on_done`` of :func:`ordered_map` for jobs that write ``sizes[i]`` files each: reports
    ``progress(stage, files written, files in all)`` (None when ``progress`` is None)."""
    if progress is None:
        return None
    written = []

    def on_done(index, _done, _total):
        written.append(sizes[index])
        progress(stage, sum(written), sum(sizes))
    return on_done


def _write_arrays(result: ScenarioResult, folder: Path, scenario_yaml: str) -> list[Path]:
    """``images.npz`` (experiment 1, raw metres) and ``images.gwy`` (every experiment)."""
    arrays = {"truth": result.truth.z, "dilated": result.dilated.z,
              "sample_pixel_size_m": np.array(result.truth.pixel_size), "sample_origin_m": np.array(result.truth.origin)}
    for name, images in result.images.items():
        arrays[f"trace_{name}"] = images.trace.z
        arrays[f"retrace_{name}"] = images.retrace.z
        arrays[f"actual_x_trace_{name}"] = images.actual_x_trace
        arrays[f"actual_x_retrace_{name}"] = images.actual_x_retrace
        if images.error_trace is not None:
            arrays[f"error_trace_{name}"] = images.error_trace
            arrays[f"error_retrace_{name}"] = images.error_retrace
    if result.images:
        first = next(iter(result.images.values())).trace
        arrays["image_pixel_size_m"] = np.array(first.pixel_size)
        arrays["image_origin_m"] = np.array(first.origin)
    np.savez_compressed(folder / "images.npz", **arrays)
    written = [folder / "images.npz"]
    frames = result.frames or [{n: (im.trace, im.retrace) for n, im in result.images.items()}]
    if result.images:
        meta = {"line rate (Hz)": repr(float(result.scenario.scan.line_rate_hz)),
                "scenario": result.scenario.name, "scenario (YAML)": scenario_yaml}
        errors = {name: tuple(HeightMap(e, im.trace.pixel_size, im.trace.origin)
                              for e in (im.error_trace, im.error_retrace))
                  for name, im in result.images.items() if im.error_trace is not None}
        written.append(write_gwy(folder / "images.gwy", gwy_channels(frames, result.truth, errors), meta=meta))
    return written
