"""afmsim's own ``.npz`` images: a run's ``images.npz`` or a plain trace/retrace ``.npz``.

* ``images.npz`` (``afmsim run``): ``trace_<controller>``/``retrace_<controller>`` become channels
  named after the controller (directions ``trace``/``retrace``), ``error_trace_<controller>``/
  ``error_retrace_<controller>`` deflection channels of the same name (the Z loop's error signal,
  m), ``truth``/``dilated`` the sample and the surface the tip sees (no direction); sizes from
  ``image_pixel_size_m`` / ``sample_pixel_size_m``; the line time from ``scenario.yaml`` beside the
  file (``1 / (2 · scan.line_rate_hz)``), else none.
* a plain ``.npz`` with ``trace``, ``retrace``, ``scan_size_m`` and optionally ``line_rate_hz``
  (Hz, one line = trace + retrace) and ``scan_offset_m``; the pair becomes a channel ``height``,
  optional ``error_trace``/``error_retrace`` (m) a deflection channel ``error``.

Rows are lines in scan order (+y), columns left → right in both directions, heights in metres.
``Channel.offset_m`` is the window's lower-left corner in stage coordinates: ``scan_offset_m``, or
``image_origin_m`` (the centre of pixel [0, 0]) less half a pixel.
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


def _numbers(path: Path, arrays: dict, key: str, count: int, unit: str) -> tuple[float, ...]:
    """``arrays[key]`` as ``count`` finite numbers, else one line naming the key."""
    values = np.asarray(arrays[key]).ravel()
    if values.size != count or not np.issubdtype(values.dtype, np.number) or not np.all(np.isfinite(values)):
        raise ReaderError(f"{path.name}: {key} must be {count} finite number(s) ({unit}), got {values.tolist()}")
    return tuple(float(v) for v in values)


def _images(path: Path, arrays: dict, keys) -> dict[str, np.ndarray]:
    """The 2-D numeric arrays under ``keys`` as float64, else one line naming the first bad key."""
    out = {}
    for key in keys:
        value = np.asarray(arrays[key])
        if value.ndim != 2 or not np.issubdtype(value.dtype, np.number):
            raise ReaderError(f"{path.name}: {key} must be a 2-D numeric array (lines × pixels), got shape "
                              f"{value.shape} of {value.dtype}")
        out[key] = value.astype(np.float64)
    return out


def _plain_pair(path: Path, arrays: dict) -> list[Channel]:
    missing = [k for k in ("trace", "retrace", "scan_size_m") if k not in arrays]
    if missing:
        raise ReaderError(f"{path.name} lacks key(s) {missing}; need trace, retrace, scan_size_m "
                          "(line_rate_hz, scan_offset_m optional)")
    images = _images(path, arrays, ("trace", "retrace"))
    size = _numbers(path, arrays, "scan_size_m", 2, "m")
    line_time = None
    if "line_rate_hz" in arrays:
        rate = _numbers(path, arrays, "line_rate_hz", 1, "Hz")[0]
        if not rate > 0:
            raise ReaderError(f"{path.name}: line_rate_hz must be positive (Hz), got {rate}")
        line_time = 1.0 / (2.0 * rate)
    offset = _numbers(path, arrays, "scan_offset_m", 2, "m") if "scan_offset_m" in arrays else None
    channels = [Channel("height", direction, "height", "m", images[direction], size, line_time, offset)
                for direction in ("trace", "retrace")]
    errors = [k for k in ("error_trace", "error_retrace") if k in arrays]
    for key, image in _images(path, arrays, errors).items():
        channels.append(Channel("error", key.partition("_")[2], "deflection", "m", image, size, line_time, offset))
    return channels


def _run_images(path: Path, arrays: dict) -> list[Channel]:
    pixel = _numbers(path, arrays, "image_pixel_size_m", 2, "m")
    origin = _numbers(path, arrays, "image_origin_m", 2, "m") if "image_origin_m" in arrays else None
    offset = None if origin is None else (origin[0] - pixel[0] / 2, origin[1] - pixel[1] / 2)
    line_time = _scenario_line_time(path)
    keys = [k for k in arrays if k.partition("_")[0] in ("trace", "retrace") and k.partition("_")[2]]
    errors = [k for k in arrays if k.startswith(("error_trace_", "error_retrace_")) and k.count("_") >= 2]
    channels = []
    for key, image in _images(path, arrays, keys + errors).items():
        quantity, key = ("deflection", key.partition("_")[2]) if key in errors else ("height", key)
        direction, _, name = key.partition("_")
        size = (pixel[0] * image.shape[1], pixel[1] * image.shape[0])
        channels.append(Channel(name, direction, quantity, "m", image, size, line_time, offset))
    samples = [k for k in ("truth", "dilated") if k in arrays and "sample_pixel_size_m" in arrays]
    if samples:
        sample_pixel = _numbers(path, arrays, "sample_pixel_size_m", 2, "m")
        for key, image in _images(path, arrays, samples).items():
            size = (sample_pixel[0] * image.shape[1], sample_pixel[1] * image.shape[0])
            channels.append(Channel(key, "", "height", "m", image, size, None))
    return channels


def read_npz(path: Path) -> AfmFile:
    """The height images of an afmsim ``.npz`` as channels; a bad key is one line naming it."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise ReaderError(f"{path.name}: not a readable .npz file ({type(error).__name__})") from None
    if "trace" in arrays or "retrace" in arrays:
        channels = _plain_pair(path, arrays)
    elif "image_pixel_size_m" in arrays:
        channels = _run_images(path, arrays)
    else:
        channels = []
    if not channels:
        raise ReaderError(f"{path.name}: no afmsim images (trace/retrace, or trace_<c>/retrace_<c> with "
                          "image_pixel_size_m)")
    return AfmFile(path, "npz", tuple(channels), {"arrays": sorted(arrays)})
