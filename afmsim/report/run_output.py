"""Writing a scenario run into its folder: images, raw arrays, metrics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from afmsim.experiment import ScenarioResult
from afmsim.runio import write_json

from .figures import plot_trace_retrace

__all__ = ["write_run"]


def write_run(result: ScenarioResult, folder) -> list[Path]:
    """Write ``metrics.json``, ``images.npz``, ``scenario.yaml`` and one PNG per controller.

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
    return written + [folder / "metrics.json", folder / "images.npz"]
