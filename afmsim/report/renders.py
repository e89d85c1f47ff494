"""3D views of a run: trace/retrace of every controller and the true sample, on one z range.

Used by :func:`afmsim.report.run_output.write_run` (every ``afmsim run``) and by
``afmsim render RUN_DIR`` (re-rendering a written run from ``images.npz`` + ``scenario.yaml``).

Files written into the run folder:

* ``render_<controller>_trace.png`` / ``render_<controller>_retrace.png``
* ``render_sample.png`` — the sample mesh when there is one, else the true height map.

All views share one ``z_range_m`` (min/max over the true sample height map and every image), so
colours, vertical exaggeration and camera are identical across files and comparable by eye.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from afmsim.samples.heightmap import HeightMap

__all__ = ["RENDER_SIZE", "common_z_range", "render_run_views", "load_run_arrays", "render_names"]

#: Window size of every run render (width, height), pixels.
RENDER_SIZE = (1000, 750)


def common_z_range(truth: HeightMap | None, images: dict) -> tuple[float, float]:
    """(low, high) in metres over the true sample and every trace/retrace image."""
    arrays = [truth.z] if truth is not None else []
    for trace, retrace in images.values():
        arrays += [trace.z, retrace.z]
    lo, hi = float(min(a.min() for a in arrays)), float(max(a.max() for a in arrays))
    # Whole nanometres outward (ignoring sub-0.01 nm round-off) so colour-bar labels read cleanly.
    nm = 1e-9
    return float(np.floor(lo / nm + 0.01) * nm), float(np.ceil(hi / nm - 0.01) * nm)


def render_names(controllers) -> list[str]:
    """File names of the renders a run with these controllers gets."""
    names = [f"render_{c}_{d}.png" for c in controllers for d in ("trace", "retrace")]
    return names + ["render_sample.png"]


def render_run_views(images: dict, truth: HeightMap, mesh, folder, *, name: str = "run",
                     interactive: bool = False, window_size=RENDER_SIZE) -> tuple[list[Path], str | None]:
    """Render every controller's trace and retrace and the sample into ``folder``.

    Parameters
    ----------
    images : dict
        controller → ``(trace HeightMap, retrace HeightMap)``.
    truth : HeightMap
        The true sample (rendered as a surface when ``mesh`` is None).
    mesh : trimesh.Trimesh or None
        The sample mesh, vertices in metres.
    name : str
        Scenario name, used in titles.
    interactive : bool
        Open each view in a window (needs a display).

    Returns
    -------
    (paths, warning)
        The PNGs written, and ``None`` — or, when this machine cannot render, no paths and a
        one-line warning saying why (the run is not failed for it).
    """
    from afmsim.render import render_height_map, render_mesh, rendering_available

    if not interactive:
        ok, reason = rendering_available()
        if not ok:
            return [], f"3D renders skipped: off-screen rendering is not available here ({reason})"
    folder = Path(folder)
    z_range = common_z_range(truth, images)
    common = dict(z_range_m=z_range, window_size=window_size, interactive=interactive)
    written = []
    for controller, (trace, retrace) in images.items():
        for direction, hmap in (("trace", trace), ("retrace", retrace)):
            written.append(render_height_map(
                hmap, folder / f"render_{controller}_{direction}.png",
                title=f"{name}: {controller} — {direction}", **common))
    if mesh is not None:
        written.append(render_mesh(mesh, folder / "render_sample.png", title=f"{name}: true sample (mesh)", **common))
    else:
        written.append(render_height_map(truth, folder / "render_sample.png",
                                         title=f"{name}: true sample (height map)", **common))
    return written, None


def _hmap(arrays, key: str, grid: str) -> HeightMap:
    return HeightMap(arrays[key], tuple(arrays[f"{grid}_pixel_size_m"]), tuple(arrays[f"{grid}_origin_m"]))


def load_run_arrays(folder):
    """Read a written run back: ``(scenario, images, truth)`` from ``scenario.yaml`` and ``images.npz``.

    ``images`` maps controller → ``(trace, retrace)`` HeightMaps (controllers in file order).
    Raises ``FileNotFoundError``/``ValueError`` with a one-line message when ``folder`` is not a run.
    """
    import yaml

    from afmsim.scenario import parse_scenario

    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} is not a folder")
    missing = [f for f in ("images.npz", "scenario.yaml") if not (folder / f).is_file()]
    if missing:
        raise FileNotFoundError(f"{folder} is not an afmsim run folder (missing {', '.join(missing)})")
    scenario = parse_scenario(yaml.safe_load((folder / "scenario.yaml").read_text()))
    with np.load(folder / "images.npz") as data:
        arrays = {k: data[k] for k in data.files}
    if "truth" not in arrays:
        raise ValueError(f"{folder / 'images.npz'} has no 'truth' array: not an afmsim run")
    truth = _hmap(arrays, "truth", "sample")
    images = {}
    for key in arrays:
        if key.startswith("trace_"):
            c = key[len("trace_"):]
            images[c] = (_hmap({**arrays, "z": arrays[key]}, "z", "image"),
                         _hmap({**arrays, "z": arrays[f"retrace_{c}"]}, "z", "image"))
    return scenario, images, truth


def rebuild_mesh(scenario):
    """The sample mesh of a scenario (micro-lens arrays), or None — rebuilt, not stored in runs."""
    if scenario.sample.kind != "microlens":
        return None
    from afmsim.experiment import build_sample, scan_geometry

    return build_sample(scenario, scan_geometry(scenario))[1]
