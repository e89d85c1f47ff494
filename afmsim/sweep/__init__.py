"""Parameter sweeps: many scenarios that differ in a few values, run as Dask tasks.

``spec`` reads and expands a sweep file into validated runs, ``execute`` runs them on a Dask
cluster with a checkpoint per finished run (resumable), ``tables`` and ``plot`` write the
results table and the summary figure, ``progress`` draws the terminal bar.

    from afmsim.sweep import load_sweep, run_sweep
    table = run_sweep(load_sweep("scenarios/sweep-scan-size.yaml"), "outputs/my-sweep")
"""

from afmsim.sweep.execute import SweepRunError, default_workers, local_cluster, result_row, run_one, run_sweep
from afmsim.sweep.spec import MAX_RUNS, Run, Sweep, SweepError, load_sweep, parse_sweep

__all__ = ["MAX_RUNS", "Run", "Sweep", "SweepError", "SweepRunError", "default_workers", "load_sweep", "local_cluster", "parse_sweep",
           "result_row", "run_one", "run_sweep"]
