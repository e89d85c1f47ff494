"""The run's 3D renders in a forked process of their own, warmed up while the run simulates.

Off-screen rendering has a fixed start-up cost — importing pyvista/VTK and opening the EGL context:
about 0.7 CPU-second on the 2-core VM, three times a render's own cost. A
:class:`RenderProcess` pays it as soon as it is started (``afmsim run`` starts it before the
simulation, whose sample build and worker start-up leave a core idle), then draws the renders
it is sent beside the figures.

The process is also the rendering check: a GL stack that crashes, hangs or draws blank kills or
fails that process only, and the run goes on with a one-line warning, no renders and no partial
files.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
from collections.abc import Callable
from pathlib import Path

__all__ = ["RenderProcess", "start_renders", "RENDER_TIMEOUT_S"]

#: Longest wait (s) for one render before the render process is stopped and the run goes on.
RENDER_TIMEOUT_S = 120.0

_ADVICE = "on Debian/Ubuntu install libegl1 and libgl1-mesa-dri"
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


class RenderProcess:
    """A forked process that prepares off-screen rendering at once (``warm=True``) and then runs
    one ``draw()`` it is sent (:meth:`submit`).

    ``draw`` (pickled on its way: it must be a module-level function or a :func:`functools.partial`
    of one) writes the PNGs and returns their paths. Where ``fork`` is missing the draw runs in the
    caller, after the :func:`afmsim.render.rendering_available` probe.
    """

    def __init__(self, *, warm: bool = True):
        self.forked = "fork" in multiprocessing.get_all_start_methods()
        self._submitted = False
        if not self.forked:  # pragma: no cover - not on Linux
            return
        self._answers, answer_end = multiprocessing.Pipe(duplex=False)
        job_end, self._jobs = multiprocessing.Pipe(duplex=False)
        self._process = multiprocessing.get_context("fork").Process(
            target=_serve, args=(job_end, answer_end, warm, (self._jobs, self._answers), os.getpid()), daemon=True)
        self._process.start()
        answer_end.close()
        job_end.close()

    def submit(self, draw, files) -> Callable[[], tuple[list[Path], str | None]]:
        """Send ``draw`` (it writes ``files``); returns ``wait() -> (paths, warning)``."""
        if self._submitted:
            raise RuntimeError("a RenderProcess draws once")
        self._submitted = True
        if not self.forked:  # pragma: no cover - not on Linux
            from .renders import render_unavailable

            warning = render_unavailable()
            paths = [] if warning else draw()
            return lambda: (paths, warning)
        try:
            self._jobs.send(draw)
        except (BrokenPipeError, EOFError):  # the process already died (its warm-up crashed)
            pass
        self._jobs.close()
        timeout = RENDER_TIMEOUT_S * (1 + len(files))

        def wait():
            answer = None
            try:
                if self._answers.poll(timeout):
                    answer = self._answers.recv()
                else:
                    self._process.kill()
                    answer = f"no render after {timeout:.0f} s (GL stack hung)"
            except EOFError:  # the process died without a word
                pass
            self._process.join()
            if isinstance(answer, list) and self._process.exitcode == 0:
                return answer, None
            if isinstance(answer, str):
                why = answer
            elif self._process.exitcode is not None and self._process.exitcode < 0:
                why = f"the rendering process was killed by signal {-self._process.exitcode} (GL stack crashed)"
            else:
                why = f"the rendering process failed (exit {self._process.exitcode})"
            for path in files:
                Path(path).unlink(missing_ok=True)
            return [], f"3D renders skipped: off-screen rendering failed here ({why}) — {_ADVICE}"
        return wait

    def close(self) -> None:
        """Stop the process without drawing (a run with no renders, or one that failed)."""
        if self.forked and not self._submitted:
            self._submitted = True
            self._jobs.close()  # the process reads EOF and exits
            self._process.join(timeout=5.0)
            if self._process.is_alive():  # still warming up a slow GL stack
                self._process.kill()
                self._process.join()


def start_renders(draw, files) -> Callable[[], tuple[list[Path], str | None]]:
    """Run ``draw()`` (it writes the PNGs ``files`` and returns their paths) in a fresh render
    process, not warmed up; returns ``wait() -> (paths, warning)``."""
    if not files:
        return lambda: ([], None)
    return RenderProcess(warm=False).submit(draw, files)


def _serve(jobs, answers, warm: bool, callers_ends, parent: int) -> None:
    """In the render process: warm up, wait for ``draw``, run it, send its paths or the one-line
    reason it failed. A warm-up failure is kept and sent as the answer to the draw.
    ``callers_ends``, the caller's ends of both pipes, are closed here at once (a forked copy of
    the job pipe's sending end would keep this process from ever reading its end); ``parent`` is
    the caller's process id."""
    for end in callers_ends:
        end.close()
    _die_with_parent(parent)
    failure = None
    if warm:
        try:
            _warm_up()
        except Exception as error:  # noqa: BLE001 - reported when a draw is asked for
            failure = _one_line(error)
    try:
        draw = jobs.recv()
    except EOFError:  # closed without a job: nothing to draw
        return
    if failure is None:
        try:
            answer = draw()
        except Exception as error:  # noqa: BLE001 - any failure to render is reported, the run stands
            answer = _one_line(error)
    else:
        answer = failure
    answers.send(answer)
    answers.close()


def _warm_up() -> None:
    """Import VTK and open the off-screen GL context with one empty frame (a 16 × 16 window): the
    first render's set-up, paid here; the run's renders then cost what later renders do."""
    import afmsim.render  # noqa: F401  (chooses the off-screen EGL window before VTK opens a window)
    import pyvista

    plotter = pyvista.Plotter(off_screen=True, window_size=(16, 16))
    try:
        if plotter.screenshot(None, return_img=True) is None:
            raise RuntimeError("the off-screen GL context drew nothing")
    finally:
        plotter.close()


def _die_with_parent(parent: int) -> None:
    """Have the kernel kill this process when the caller dies (Linux ``PR_SET_PDEATHSIG``): a run
    killed by a signal leaves no render process behind holding its terminal or pipes."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):  # pragma: no cover - not Linux: the daemon flag ends it at a normal exit
        return
    if os.getppid() != parent:  # the caller died before the line above
        os._exit(0)


def _one_line(error: Exception) -> str:
    return f"{type(error).__name__}: {(str(error).splitlines() or [''])[0]}"
