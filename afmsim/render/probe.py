"""Can this machine render? Probed in a subprocess so a crashing GL stack cannot kill the caller."""

from __future__ import annotations

import functools
import os
import subprocess
import sys

__all__ = ["rendering_available", "start_rendering_probe", "RenderingUnavailable"]


class RenderingUnavailable(RuntimeError):
    """Rendering (off-screen or interactive) is impossible in this environment."""


# Self-contained: the child inherits os.environ, which already carries the window choice made
# in ``afmsim/render/__init__.py``; it does not import afmsim (no sys.path assumptions). It draws
# with VTK's own modules, the ones pyvista renders through (a third of pyvista's start-up time),
# and checks that pyvista is installed without importing it.
_PROBE = r"""
import importlib.util, sys
if importlib.util.find_spec("pyvista") is None:
    print("PROBE-FAIL pyvista is not installed", flush=True)
    sys.exit(3)
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the OpenGL render window)
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkFiltersSources import vtkSphereSource
from vtkmodules.vtkRenderingCore import (vtkActor, vtkPolyDataMapper, vtkRenderer, vtkRenderWindow,
                                         vtkWindowToImageFilter)
sphere = vtkSphereSource()  # kept referenced: the pipeline does not own its source
mapper = vtkPolyDataMapper()
mapper.SetInputConnection(sphere.GetOutputPort())
actor = vtkActor()
actor.SetMapper(mapper)
actor.GetProperty().SetColor(1.0, 0.0, 0.0)
renderer = vtkRenderer()
renderer.AddActor(actor)
window = vtkRenderWindow()
window.SetOffScreenRendering(1)
window.AddRenderer(renderer)
window.SetSize(64, 48)
window.Render()
grab = vtkWindowToImageFilter()
grab.SetInput(window)
grab.Update()
img = vtk_to_numpy(grab.GetOutput().GetPointData().GetScalars())
caps = window.ReportCapabilities() or ""
name = type(window).__name__
window.Finalize()
if img is None or img.shape[0] != 64 * 48 or float(img.std()) == 0.0:
    print("PROBE-FAIL blank or wrong-size image", flush=True)
    sys.exit(3)
renderer = next((l.split(":", 1)[1].strip() for l in caps.splitlines()
                 if "renderer string" in l.lower()), "unknown renderer")
print(f"PROBE-OK {name}; {renderer}", flush=True)
"""


_PENDING: dict = {}


def start_rendering_probe() -> None:
    """Start the probe in the background, so that a later :func:`rendering_available` (in this
    process) finds its answer ready instead of waiting a second or more for it. Idempotent."""
    if "proc" in _PENDING or rendering_available.cache_info().currsize:
        return
    try:
        _PENDING["proc"] = subprocess.Popen([sys.executable, "-c", _PROBE], stdout=subprocess.PIPE,
                                            stderr=subprocess.PIPE, text=True, env=dict(os.environ))
    except OSError as exc:  # pragma: no cover - cannot start Python at all
        _PENDING["error"] = f"could not start the rendering probe: {exc}"


@functools.lru_cache(maxsize=1)
def rendering_available(timeout: float = 120.0) -> tuple[bool, str]:
    """Probe off-screen rendering in a fresh Python process (the one :func:`start_rendering_probe`
    started, if any).

    Returns
    -------
    (ok, reason)
        ``(True, "<window class>; <OpenGL renderer>")`` when a small scene rendered to a
        non-blank image, else ``(False, why)`` — import failure, crash (signal), time-out, or
        the tail of the child's stderr. The answer is cached for the process.
    """
    start_rendering_probe()
    if "error" in _PENDING:  # pragma: no cover
        return False, _PENDING.pop("error")
    proc = _PENDING.pop("proc")
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        return False, f"rendering probe timed out after {timeout:.0f} s"
    for line in stdout.splitlines():
        if line.startswith("PROBE-OK"):
            return True, line[len("PROBE-OK "):]
    if proc.returncode < 0:
        what = f"rendering probe killed by signal {-proc.returncode} (GL stack crashed)"
    else:
        what = f"rendering probe failed (exit {proc.returncode})"
    tail = (stderr.strip() or stdout.strip()).splitlines()[-3:]
    hint = " — on Debian/Ubuntu install libegl1 and libgl1-mesa-dri"
    return False, what + (": " + " | ".join(tail) if tail else "") + hint
