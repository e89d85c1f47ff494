"""Writing a scenario run into its folder: images, raw arrays, metrics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from afmsim.experiment import ScenarioResult
from afmsim.runio import write_json

from .document import write_report
from .figures import plot_trace_retrace
from .gwy import write_gwy
from .paper_figures import plot_binarized, plot_scan_figure
from .renders import render_run_views
from .tables import nsl2_markdown, write_nsl2_table

__all__ = ["write_run", "gwy_channels"]


def gwy_channels(images: dict, truth) -> dict:
    """The ``images.gwy`` channels: "trace <c>", "retrace <c>" per controller, then "topography"."""
    channels = {}
    for name, (trace, retrace) in images.items():
        channels[f"trace {name}"] = trace
        channels[f"retrace {name}"] = retrace
    channels["topography"] = truth
    return channels


def write_run(result: ScenarioResult, folder, *, renders: bool = True) -> list[Path]:
    """Write ``metrics.json``, ``images.npz``, ``scenario.yaml``, one PNG per controller, and the
    report: ``images.gwy``, ``figure_<c>.png`` (Fig. 10–13 analogue), ``binarized.png``,
    ``nsl2_table.md/.csv`` (Table 3/4 analogue), 3D ``render_*.png`` (skipped with a warning in
    the report where this machine cannot render, or with ``renders=False``), ``report.html``
    (self-contained) and ``report.md``.

    ``images.npz`` holds ``trace_<controller>``/``retrace_<controller>`` (heights in metres, rows =
    lines, columns = pixels left → right), ``truth`` and ``dilated`` (the sample and the surface the
    tip sees, on the simulation grid), and the grids' ``*_pixel_size_m``/``*_origin_m``.
    """
    folder = Path(folder)
    written = []
    write_json(folder / "metrics.json", result.metrics())
    (folder / "scenario.yaml").write_text(yaml.safe_dump(result.scenario.model_dump(mode="json"), sort_keys=False))
    arrays = {"truth": result.truth.z, "dilated": result.dilated.z,
              "sample_pixel_size_m": np.array(result.truth.pixel_size), "sample_origin_m": np.array(result.truth.origin)}
    for name, images in result.images.items():
        arrays[f"trace_{name}"] = images.trace.z
        arrays[f"retrace_{name}"] = images.retrace.z
        arrays[f"actual_x_trace_{name}"] = images.actual_x_trace
        arrays[f"actual_x_retrace_{name}"] = images.actual_x_retrace
        written.append(plot_trace_retrace(images.trace, images.retrace, folder / f"image_{name}.png",
                                          title=f"{result.scenario.name}: controller '{name}' (experiment 1)"))
    if result.images:
        first = next(iter(result.images.values())).trace
        arrays["image_pixel_size_m"] = np.array(first.pixel_size)
        arrays["image_origin_m"] = np.array(first.origin)
    np.savez_compressed(folder / "images.npz", **arrays)
    written += [folder / "metrics.json", folder / "images.npz"]
    written += _write_report_files(result, folder, renders=renders)
    return written


def _write_report_files(result: ScenarioResult, folder: Path, *, renders: bool) -> list[Path]:
    scenario, kind = result.scenario, result.scenario.sample.kind
    pairs = {name: (im.trace, im.retrace) for name, im in result.images.items()}
    written = [write_gwy(folder / "images.gwy", gwy_channels(pairs, result.truth))] if pairs else []
    metrics = result.metrics()
    table, paths = write_nsl2_table(metrics, kind, folder)
    written += paths
    figures = [plot_scan_figure(trace, retrace, folder / f"figure_{name}.png", kind=kind,
                                title=f"{scenario.name}: controller '{name}' (experiment 1)")
               for name, (trace, retrace) in pairs.items()]
    binarized = [plot_binarized(pairs, folder / "binarized.png",
                                title=f"{scenario.name}: binarized images used for NSL2 (experiment 1)")] if pairs else []
    warnings, views = [], []
    if renders:
        views, warning = render_run_views(pairs, result.truth, result.mesh, folder, name=scenario.name)
        if warning:
            warnings.append(warning)
    else:
        warnings.append("3D renders skipped (renders=False)")
    written += figures + binarized + views
    sections = [("Height images (trace / retrace)", [folder / f"image_{n}.png" for n in pairs]),
                ("Paper figure analogues (Fig. 10–13)", figures),
                ("Binarized images (NSL2)", binarized),
                ("3D renders", views)]
    written += write_report(folder, name=scenario.name, scenario_yaml=(folder / "scenario.yaml").read_text(),
                            metrics=metrics, nsl2_md=nsl2_markdown(table), sections=sections, warnings=warnings)
    return written
