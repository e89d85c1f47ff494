"""A terminal progress bar for sweeps: runs done / total, elapsed and estimated time left."""

from __future__ import annotations

from contextlib import contextmanager, nullcontext

__all__ = ["sweep_progress"]


def sweep_progress(show: bool):
    """A context manager yielding ``progress(done, total, label)`` for :func:`run_sweep`, or None.

    With ``show`` a rich bar (runs done/total, elapsed, time left) is drawn on stderr and removed
    when the sweep ends; without it nothing is drawn and the context yields None.
    """
    if not show:
        return nullcontext(None)

    @contextmanager
    def bar():
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        with Progress(TextColumn("sweep"), BarColumn(), MofNCompleteColumn(), TextColumn("runs"), TimeElapsedColumn(),
                      TextColumn("left"), TimeRemainingColumn(), console=Console(stderr=True), transient=True) as prog:
            task = prog.add_task("sweep", total=None)
            started = []

            def update(done, total, label):
                if started:
                    prog.update(task, completed=done, total=total)
                else:  # runs resumed from checkpoints must not count towards the speed estimate
                    prog.reset(task, completed=done, total=total)
                    started.append(label)
            yield update
    return bar()
