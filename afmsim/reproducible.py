"""Bit-identical results wherever a computation runs: one BLAS thread inside afmsim's entry points.

OpenBLAS splits large products and least-squares solves over its threads, and the split changes
the rounding: the same seeded 128 × 128 run scored NSL2 801.1664995039039 in a process with two
BLAS threads and 801.1664995038985 in a Dask worker (which Dask starts with one). The public
entry points that compute results (:func:`afmsim.experiment.run_scenario`,
:func:`afmsim.identification.identify`, the loop and image diagnoses) run under
:func:`single_blas_thread`, so a seeded run gives the same bits serially, in a sweep, on a
cluster. Environment variables cannot do this once numpy is imported; ``threadpoolctl`` can. The
linear algebra here is small (least squares with tens of columns), so one thread costs no
measurable time.
"""

from __future__ import annotations

from functools import wraps

from threadpoolctl import threadpool_limits

__all__ = ["single_blas_thread"]


def single_blas_thread(func):
    """Decorator: run ``func`` with every loaded BLAS library limited to one thread."""

    @wraps(func)
    def limited(*args, **kwargs):
        with threadpool_limits(limits=1, user_api="blas"):
            return func(*args, **kwargs)

    return limited
