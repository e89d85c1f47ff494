"""Running a sweep on Dask: one task per run, a durable checkpoint per finished run, resumable.

Every run is one :mod:`dask.distributed` task that calls :func:`afmsim.experiment.run_scenario`
and returns one flat row (:func:`result_row`). Rows are gathered with ``as_completed`` and each
is written to ``DIR/runs/<run_id>.json`` the moment it arrives, so an interrupted sweep (Ctrl-C,
a dead worker, a lost machine) keeps every finished run and ``resume=True`` computes only the
missing ones. A sweep folder therefore grows in place instead of appearing by one atomic rename;
what tells a finished sweep from an interrupted one is ``manifest.json``, written last, after the
tables (``results.csv``/``.parquet``, each written to a temporary file and renamed) and the plot.
A resumed sweep removes the manifest before it computes anything.

Layout of ``DIR``: ``sweep.json`` (the expanded sweep, written first), ``runs/`` (checkpoints),
``failures.json`` (only while runs fail), ``results.csv``, ``results.parquet``, ``summary.png``,
``manifest.json``.
"""

from __future__ import annotations

import json
import logging
import os
import platform
import sys
import time
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path

import pandas as pd

from afmsim.experiment import run_scenario
from afmsim.runio import git_revision, versions, write_json
from afmsim.sweep.plot import summary_figure
from afmsim.sweep.spec import Run, Sweep, SweepError
from afmsim.sweep.tables import read_rows, replace_atomically, write_tables

__all__ = ["SweepRunError", "run_sweep", "run_one", "result_row", "default_workers", "local_cluster"]


class SweepRunError(RuntimeError):
    """Some runs of a sweep failed; the finished ones are checkpointed and ``resume`` retries the rest."""


def default_workers() -> int:
    """Worker processes of the default local cluster: one per CPU core this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def result_row(run: Run, metrics: dict, wall_s: float) -> dict:
    """One table row: ``run_id``, the swept values (column = dotted path) and the scores.

    Scores are ``<controller>.<metric>_mean`` / ``_std`` for every metric of
    :meth:`afmsim.experiment.ScenarioResult.metrics` (NSL2 dimensionless, shifts in m), ``e_D``
    (eq. 9, fraction) when SPI and DIAPI both ran, and ``wall_s``, the run's wall time (s).
    """
    row = {"run_id": run.run_id, **run.params}
    for controller, scores in metrics["controllers"].items():
        for metric, summary in scores.items():
            row[f"{controller}.{metric}_mean"] = summary["mean"]
            row[f"{controller}.{metric}_std"] = summary["std"]
    if "e_D" in metrics:
        row["e_D"] = metrics["e_D"]
    row["wall_s"] = wall_s
    return row


def run_one(run: Run) -> dict:
    """The task a Dask worker executes: run the scenario and return its row (:func:`result_row`)."""
    start = time.perf_counter()
    metrics = run_scenario(run.scenario).metrics()
    return result_row(run, metrics, time.perf_counter() - start)


@contextmanager
def _client(scheduler, workers):
    """A ``dask.distributed.Client``: on ``scheduler`` if given, else on a fresh local cluster."""
    from dask.distributed import Client

    if scheduler is not None:
        with Client(scheduler, timeout="10s") as client:
            yield client, str(scheduler)
        return
    n = workers or default_workers()
    with local_cluster(n) as cluster, Client(cluster) as client:
        yield client, f"LocalCluster({n} worker processes × 1 thread)"


def local_cluster(n_workers: int):
    """The default cluster: ``n_workers`` processes of one thread each, on this machine.

    Dask's nannies start workers with ``MALLOC_TRIM_THRESHOLD_=65536`` to return freed memory to
    the system early. Setting that variable also switches off glibc's adaptive mmap threshold, so
    every array above 128 KiB is a fresh ``mmap`` whose pages fault in again on first touch; a
    run's many short-lived 0.1–10 MB arrays then cost ~7× the page faults and ~30 % of its wall
    time (measured on the micro-lens runs of ``benchmarks/bench_sweep.py``). The variable is
    left unset for afmsim's own workers (the thread caps ``OMP_NUM_THREADS=1`` etc. stay). The
    workers' statistical profiler (a stack sample of the running task every 10 ms, for the
    dashboard's profile page) is switched off too: it took the GIL from the runs, which ran at
    0.87 of plain worker processes' speed with it and 0.94 without. An existing cluster given by
    address keeps its own settings.
    """
    import dask
    from dask.distributed import LocalCluster

    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                          "distributed.worker.profile.enabled": False}):
        return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                            silence_logs=logging.ERROR)


def _sweep_record(sweep: Sweep) -> dict:
    return {"name": sweep.name, "seed": sweep.seed, "fingerprint": sweep.fingerprint(),
            "parameters": list(sweep.parameters), "base": sweep.base.model_dump(mode="json"),
            "spec": sweep.spec.model_dump(mode="json", exclude={"base"}),
            "runs": [{"run_id": run.run_id, "params": run.params} for run in sweep.runs()]}


def _prepare(out_dir: Path, sweep: Sweep, resume: bool) -> None:
    """Create the sweep folder, or check that a folder to resume holds this very sweep."""
    record = out_dir / "sweep.json"
    if out_dir.exists():
        try:
            found = json.loads(record.read_text()).get("fingerprint")
        except (OSError, ValueError, AttributeError):
            raise SweepError(f"--out {out_dir}: not a sweep folder (no readable sweep.json); cannot resume it") from None
        if found != sweep.fingerprint():
            raise SweepError(f"--out {out_dir}: holds a different sweep (fingerprint {found}, this one "
                             f"{sweep.fingerprint()}); choose another --out")
        (out_dir / "manifest.json").unlink(missing_ok=True)
    else:
        out_dir.mkdir(parents=True)
        write_json(record, _sweep_record(sweep))
    (out_dir / "runs").mkdir(exist_ok=True)


def _compute(client, todo: list[Run], runs_dir: Path, key_prefix: str, progress, done: int, total: int):
    """Submit ``todo``, checkpoint each row as it arrives; return (computed run ids, failures)."""
    from dask.distributed import as_completed

    by_key = {f"{key_prefix}-{run.run_id}": run for run in todo}
    # one batched submission; each result travels with its completion notice (no round trip per run)
    futures = client.map(run_one, todo, key=list(by_key), pure=False)
    computed, failures = [], []
    for future, row in as_completed(futures, with_results=True, raise_errors=False):
        run = by_key[future.key]
        if future.status == "error":  # any failure of one run is recorded, the others go on
            error = future.exception()
            message = (str(error).splitlines() or [""])[0]
            failures.append({"run_id": run.run_id, "params": run.params, "error": f"{type(error).__name__}: {message}"})
        else:
            write_json(runs_dir / f"{run.run_id}.json", row)
            computed.append(run.run_id)
        future.release()
        done += 1
        if progress is not None:
            progress(done, total, f"run {run.run_id}")
    return computed, failures


def _versions() -> dict:
    found = versions()
    for name in ("dask", "distributed", "pandas", "pyarrow"):
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = None
    return found


def run_sweep(sweep: Sweep, out_dir, scheduler=None, resume: bool = False, progress=None,
              workers: int | None = None) -> pd.DataFrame:
    """Run every run of ``sweep`` as a Dask task and write the sweep folder ``out_dir``.

    ``scheduler``: address of a running Dask scheduler (``"tcp://host:port"``), used as it is;
    by default a :class:`~dask.distributed.LocalCluster` of ``workers`` processes (default: one per
    core, :func:`default_workers`), one thread each, is started and stopped. ``resume``: continue
    the sweep already in ``out_dir`` (it must be this same sweep), computing only runs without a
    checkpoint; without it ``out_dir`` must not exist. ``progress(done, total, label)`` is called
    after every finished run.

    Returns the results table (one row per run, in sweep order; columns as in :func:`result_row`,
    list-valued parameters as lists). Raises ``FileExistsError`` (``out_dir`` exists, no
    ``resume``), :class:`SweepError` (``out_dir`` holds another sweep), ``OSError`` (scheduler
    unreachable) and :class:`SweepRunError` when runs failed (after checkpointing the others and
    writing ``failures.json``).
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not resume:
        raise FileExistsError(f"output folder {out_dir} already exists: choose another --out, or --resume it")
    if scheduler is not None and workers is not None:
        raise ValueError("workers: applies to the local cluster only, not to an existing scheduler")
    started = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    runs = sweep.runs()
    runs_dir = out_dir / "runs"
    with _client(scheduler, workers) as (client, where):
        _prepare(out_dir, sweep, resume)
        todo = [run for run in runs if not (runs_dir / f"{run.run_id}.json").exists()]
        if progress is not None:
            progress(len(runs) - len(todo), len(runs), "resumed")
        computed, failures = _compute(client, todo, runs_dir, f"afmsim-{sweep.name}-{sweep.fingerprint()}", progress,
                                      len(runs) - len(todo), len(runs))
        n_workers = len(client.nthreads())
    failed_record = out_dir / "failures.json"
    if failures:
        write_json(failed_record, {"failed": failures})
        raise SweepRunError(f"{len(failures)} of {len(runs)} runs failed (first: run {failures[0]['run_id']}: "
                            f"{failures[0]['error']}); see {failed_record}, --resume retries them")
    failed_record.unlink(missing_ok=True)
    table = read_rows(runs_dir, runs)
    files = write_tables(table, out_dir)
    figure = summary_figure(table, list(sweep.parameters), title=sweep.name)
    files.append(replace_atomically(out_dir / "summary.png", lambda tmp: figure.savefig(tmp, format="png", dpi=110)))
    write_json(out_dir / "manifest.json", {
        "command": "sweep", "name": sweep.name, "seed": sweep.seed, "fingerprint": sweep.fingerprint(),
        "parameters": list(sweep.parameters), "runs": len(runs), "computed_now": computed,
        "resumed": len(runs) - len(todo), "scheduler": where, "workers": n_workers,
        "files": [path.name for path in files], "versions": _versions(), "git": git_revision(),
        "platform": platform.platform(), "argv": sys.argv, "started_utc": started,
        "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "units": "SI (m, V, s) for scores; swept values in the scenario's units (named in each path)",
    })
    return table
