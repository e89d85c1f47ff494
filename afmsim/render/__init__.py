"""Off-screen 3D views of height maps and sample meshes (pyvista / VTK).

Window-system choice (made here, before anything in this package creates a VTK window)
---------------------------------------------------------------------------------------
On Linux, VTK's default render window tries X11 first: without a display it prints
"bad X server connection" and falls back to EGL, and on a machine without libX11 the attempt
segfaults. This package therefore sets ``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow``
(``os.environ.setdefault``) and ``pyvista.OFF_SCREEN = True``, so renders go straight to EGL
(GPU driver or Mesa llvmpipe; needs ``libegl1`` + ``libgl1-mesa-dri`` on Debian).

* A user who set ``VTK_DEFAULT_OPENGL_WINDOW`` themselves keeps their choice, and
  ``pyvista.OFF_SCREEN`` is then left alone.
* ``render_height_map(..., interactive=True)`` / ``render_mesh(..., interactive=True)`` open a
  real window (X11) for that one plot where a display exists, and raise
  :class:`RenderingUnavailable` with a clear message where none does. VTK reads the variable
  each time it creates a window, so the per-plot switch works even after off-screen renders.

:func:`rendering_available` probes rendering in a subprocess (a broken GL stack can segfault,
which must not kill the caller) and says why not when it cannot render.
"""

from __future__ import annotations

import os
import sys

#: True when this package chose the EGL off-screen window (the user had not chosen one).
EGL_DEFAULT_CHOSEN = False
if sys.platform.startswith("linux") and "VTK_DEFAULT_OPENGL_WINDOW" not in os.environ:
    os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = "vtkEGLRenderWindow"
    EGL_DEFAULT_CHOSEN = True

import pyvista  # noqa: E402  (must come after the window choice above)

if EGL_DEFAULT_CHOSEN:
    pyvista.OFF_SCREEN = True

from afmsim.render.probe import RenderingUnavailable, rendering_available  # noqa: E402
from afmsim.render.views import (  # noqa: E402
    CAMERAS,
    DEFAULT_CMAP,
    render_height_map,
    render_mesh,
    z_exaggeration_for,
)

__all__ = [
    "render_height_map",
    "render_mesh",
    "rendering_available",
    "RenderingUnavailable",
    "z_exaggeration_for",
    "CAMERAS",
    "DEFAULT_CMAP",
    "EGL_DEFAULT_CHOSEN",
]
