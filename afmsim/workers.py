"""Independent pieces of one run on the machine's cores, in a fixed order, with the same bits.

A run's scans (experiments × controllers), its scores and its figures do not depend on one
another once the shared inputs (the tip-dilated sample, the stage, the identification records)
exist. :func:`worker_pool` forks worker processes that inherit those inputs (``fork``: nothing
is pickled on the way in, the compiled numba kernels come along); :func:`ordered_map` hands out
the pieces and returns their results in submission order, so a parallel run assembles exactly
what a serial one does. Every piece draws only from its own seeded generator and runs with one
BLAS thread (:mod:`afmsim.reproducible`), hence parallel results equal serial ones bit for bit
(``tests/test_parallel.py``).

With one worker (or where ``fork`` is missing) everything runs in the calling process. A worker
that dies (the kernel's out-of-memory killer, a signal, ``os._exit``) raises :class:`WorkerDied`
with one line saying how it died, instead of the pool's ``BrokenProcessPool``.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager

from threadpoolctl import threadpool_limits

__all__ = ["available_cores", "worker_pool", "ordered_map", "shared", "WorkerDied"]

_SHARED: dict = {}


class WorkerDied(RuntimeError):
    """A worker process of :func:`worker_pool` ended abruptly; the message is one line saying how
    (signal or exit status) and what to do."""


def _how_it_died(exit_codes) -> str:
    """``killed by signal 9 (SIGKILL) — out of memory?`` or ``exited with status 3``, from the
    workers' exit codes (the pool sends SIGTERM to the survivors, so the others name the culprit)."""
    ended = [code for code in exit_codes if code]
    culprits = [code for code in ended if code != -signal.SIGTERM] or ended
    if not culprits:
        return "cause unknown"
    code = culprits[0]
    if code > 0:
        return f"exited with status {code}"
    name = signal.Signals(-code).name if -code in signal.valid_signals() else "unknown"
    return f"killed by signal {-code} ({name})" + (" — out of memory?" if -code == signal.SIGKILL else "")


def available_cores() -> int:
    """CPU cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def shared(key: str):
    """A value given to :func:`worker_pool` as ``shared=``, in the parent and in every worker."""
    return _SHARED[key]


def _start_worker():
    threadpool_limits(limits=1, user_api="blas")


@contextmanager
def worker_pool(workers: int, **values):
    """Yield an executor with ``workers`` forked processes (or None for one worker) that see
    ``values`` through :func:`shared`; the values stay set in the calling process too."""
    previous = dict(_SHARED)
    _SHARED.update(values)
    try:
        if workers <= 1 or "fork" not in multiprocessing.get_all_start_methods():
            yield None
            return
        processes = {}
        try:
            with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                                     initializer=_start_worker) as executor:
                try:
                    yield executor
                except BrokenProcessPool:
                    # the pool forgets its processes on shut-down; their exit codes are read once it has joined them
                    processes = dict(getattr(executor, "_processes", None) or {})
                    raise
        except BrokenProcessPool:
            how = _how_it_died(p.exitcode for p in processes.values())
            raise WorkerDied(f"a worker process died ({how}); run again with fewer workers (--workers 1)") from None
    finally:
        _SHARED.clear()
        _SHARED.update(previous)


def ordered_map(executor, func, items, on_done=None, *, wait: bool = True):
    """``[func(*item) for item in items]``, on ``executor``'s workers when it is not None.

    ``on_done(index, done, total)`` is called in the calling process as each result arrives
    (``index`` into ``items``); the list returned is in the order of ``items``. With
    ``wait=False`` the pieces are only submitted and a function is returned that waits for them
    and returns the list, so the caller can work meanwhile.
    """
    items = list(items)
    total = len(items)
    if executor is None:
        out = []
        for index, item in enumerate(items):
            out.append(func(*item))
            if on_done is not None:
                on_done(index, len(out), total)
        return out if wait else (lambda: out)
    futures = [executor.submit(func, *item) for item in items]
    index_of = {future: index for index, future in enumerate(futures)}

    def collect():
        if on_done is not None:
            for done, future in enumerate(as_completed(futures), 1):
                on_done(index_of[future], done, total)
        return [f.result() for f in futures]
    return collect() if wait else collect
