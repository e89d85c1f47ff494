"""3D views of a run: trace/retrace of every controller and the true sample, on one z range.

Used by :func:`afmsim.report.run_output.write_run` (every ``afmsim run``) and by
``afmsim render RUN_DIR`` (re-rendering a written run from ``images.npz`` + ``scenario.yaml``).

Files written into the run folder:

* ``render_<controller>_trace.png`` / ``render_<controller>_retrace.png``
* ``render_sample.png`` — the sample mesh when there is one, else the true height map.

All views show heights above the substrate and share one ``z_range_m`` (min/max over the true
sample height map and every image) and one vertical exaggeration, so colours, relief and camera
are identical across files and comparable by eye.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from afmsim.samples.heightmap import HeightMap

__all__ = ["RENDER_SIZE", "common_z_range", "render_run_views", "render_jobs", "render_unavailable", "load_run_arrays",
           "render_names"]

#: Window size of every run render (width, height), pixels.
RENDER_SIZE = (800, 600)


def common_z_range(truth: HeightMap | None, images: dict) -> tuple[float, float]:
    """(low, high) in metres over the true sample and every trace/retrace image, each above its
    substrate (:func:`afmsim.report.figures.substrate_level`)."""
    from .figures import above_substrate

    arrays = [above_substrate(truth).z] if truth is not None else []
    for trace, retrace in images.values():
        arrays += [above_substrate(trace).z, above_substrate(retrace).z]
    lo, hi = float(min(a.min() for a in arrays)), float(max(a.max() for a in arrays))
    # Whole nanometres outward (ignoring sub-0.01 nm round-off) so colour-bar labels read cleanly.
    nm = 1e-9
    return float(np.floor(lo / nm + 0.01) * nm), float(np.ceil(hi / nm - 0.01) * nm)


def render_names(controllers, which: str = "all", best: str | None = None) -> list[str]:
    """File names of the renders a run with these controllers gets (``which``: all or key)."""
    if which == "key":
        chosen = list(dict.fromkeys(c for c in ("none", best) if c in controllers))
        names = [f"render_{c}_trace.png" for c in chosen]
    else:
        names = [f"render_{c}_{d}.png" for c in controllers for d in ("trace", "retrace")]
    return names + ["render_sample.png"]


def render_jobs(images: dict, truth: HeightMap, mesh, folder, *, name: str = "run", which: str = "all",
                best: str | None = None, interactive: bool = False, window_size=RENDER_SIZE) -> list[tuple]:
    """The renders of a run as ``(function, args)`` pairs, independent of one another.

    Every view shows heights above its substrate on one z range (:func:`common_z_range`) with one
    vertical exaggeration (chosen from the scan's lateral size and that range), so the sample and
    every scan are drawn alike. ``which="key"`` keeps the sample and the traces of ``none`` and
    ``best``; ``"all"`` every controller's trace and retrace.
    """
    from afmsim.render import z_exaggeration_for

    from .figures import above_substrate

    folder = Path(folder)
    z_range = common_z_range(truth, images)
    first = next(iter(images.values()))[0] if images else truth
    exaggeration = z_exaggeration_for(max(first.size), z_range[1] - z_range[0])
    common = dict(z_range_m=z_range, window_size=window_size, interactive=interactive, z_exaggeration=exaggeration)
    wanted = set(render_names(list(images), which, best))
    jobs = []
    for controller, (trace, retrace) in images.items():
        for direction, hmap in (("trace", trace), ("retrace", retrace)):
            file = f"render_{controller}_{direction}.png"
            if file in wanted:
                jobs.append((_render_map, (above_substrate(hmap), folder / file,
                                           f"{name}: {controller} — {direction}", common)))
    if mesh is not None:
        jobs.append((_render_mesh, (mesh, folder / "render_sample.png", f"{name}: true sample (mesh)", common)))
    else:
        jobs.append((_render_map, (above_substrate(truth), folder / "render_sample.png",
                                   f"{name}: true sample (height map)", common)))
    return jobs


def _render_map(hmap, path, title, common):
    from afmsim.render import render_height_map

    return render_height_map(hmap, path, title=title, **common)


def _render_mesh(mesh, path, title, common):
    from afmsim.render import render_mesh

    return render_mesh(mesh, path, title=title, **common)


def render_run_views(images: dict, truth: HeightMap, mesh, folder, *, name: str = "run",
                     interactive: bool = False, window_size=RENDER_SIZE) -> tuple[list[Path], str | None]:
    """Render every controller's trace and retrace and the sample into ``folder`` (:func:`render_jobs`,
    one after the other).

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
    warning = render_unavailable(interactive)
    if warning:
        return [], warning
    jobs = render_jobs(images, truth, mesh, folder, name=name, interactive=interactive, window_size=window_size)
    return [func(*args) for func, args in jobs], None


def render_unavailable(interactive: bool = False) -> str | None:
    """None where off-screen renders can be made here, else the one-line warning saying why."""
    from afmsim.render import rendering_available

    if interactive:
        return None
    ok, reason = rendering_available()
    return None if ok else f"3D renders skipped: off-screen rendering is not available here ({reason})"


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
