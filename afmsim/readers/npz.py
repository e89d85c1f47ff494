"""afmsim's own ``.npz`` images: a run's ``images.npz`` or a plain trace/retrace ``.npz``.

* ``images.npz`` (``afmsim run``): ``trace_<controller>``/``retrace_<controller>`` become channels
  named after the controller (directions ``trace``/``retrace``), ``truth``/``dilated`` the sample
  and the surface the tip sees (no direction); sizes from ``image_pixel_size_m`` /
  ``sample_pixel_size_m``; the line time from ``scenario.yaml`` beside the file
  (``1 / (2 · scan.line_rate_hz)``), else none.
* a plain ``.npz`` with ``trace``, ``retrace``, ``scan_size_m`` and optionally ``line_rate_hz``.

Rows are lines in scan order (+y), columns left → right in both directions, heights in metres.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from .channels import AfmFile, Channel, ReaderError

__all__ = ["read_npz"]


def _scenario_line_time(path: Path) -> float | None:
    beside = path.parent / "scenario.yaml"
    if not beside.is_file():
        return None
    from afmsim.scenario import ScenarioError, load_scenario

    try:
        return 1.0 / (2.0 * float(load_scenario(beside).scan.line_rate_hz))
    except ScenarioError:
        return None


def _size(arrays: dict, key: str, shape) -> tuple[float, float]:
    pixel = np.asarray(arrays[key], dtype=np.float64).ravel()
    return float(pixel[0] * shape[1]), float(pixel[1] * shape[0])


def read_npz(path: Path) -> AfmFile:
    """The height images of an afmsim ``.npz`` as channels."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise ReaderError(f"{path.name}: not a readable .npz file ({type(error).__name__})") from None
    images = {k: v for k, v in arrays.items() if np.ndim(v) == 2 and np.issubdtype(np.asarray(v).dtype, np.number)}
    channels = []
    if "trace" in images and "retrace" in images:
        if "scan_size_m" not in arrays:
            raise ReaderError(f"{path.name}: lacks scan_size_m (x, y in m) beside trace/retrace")
        size = tuple(float(v) for v in np.asarray(arrays["scan_size_m"], dtype=np.float64).ravel()[:2])
        rate = float(np.ravel(arrays["line_rate_hz"])[0]) if "line_rate_hz" in arrays else None
        line_time = 1.0 / (2.0 * rate) if rate and rate > 0 else None
        for direction in ("trace", "retrace"):
            channels.append(Channel("height", direction, "height", "m", images[direction].astype(np.float64),
                                    size, line_time))
    elif "image_pixel_size_m" in arrays:
        line_time = _scenario_line_time(path)
        for key in images:
            direction, _, name = key.partition("_")
            if direction in ("trace", "retrace") and name:
                size = _size(arrays, "image_pixel_size_m", images[key].shape)
                channels.append(Channel(name, direction, "height", "m", images[key].astype(np.float64), size,
                                        line_time))
        for key in ("truth", "dilated"):
            if key in images and "sample_pixel_size_m" in arrays:
                size = _size(arrays, "sample_pixel_size_m", images[key].shape)
                channels.append(Channel(key, "", "height", "m", images[key].astype(np.float64), size, None))
    if not channels:
        raise ReaderError(f"{path.name}: no afmsim images (trace/retrace, or trace_<c>/retrace_<c> with "
                          "image_pixel_size_m)")
    return AfmFile(path, "npz", tuple(channels), {"arrays": sorted(arrays)})
