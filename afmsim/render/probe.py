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
# in ``afmsim/render/__init__.py``; it does not import afmsim (no sys.path assumptions).
_PROBE = r"""
import os, sys
import pyvista as pv
pv.OFF_SCREEN = True
p = pv.Plotter(off_screen=True, window_size=(64, 48))
p.add_mesh(pv.Sphere(), color="red")
img = p.screenshot(return_img=True)
window = type(p.ren_win).__name__
try:
    caps = p.ren_win.ReportCapabilities()
except Exception:
    caps = ""
p.close()
if img is None or img.shape[:2] != (48, 64) or float(img.std()) == 0.0:
    print("PROBE-FAIL blank or wrong-size image", flush=True)
    sys.exit(3)
renderer = next((l.split(":", 1)[1].strip() for l in caps.splitlines()
                 if "renderer string" in l.lower()), "unknown renderer")
print(f"PROBE-OK {window}; {renderer}", flush=True)
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
