"""The sweep's results table: rows read back from the run checkpoints, written as CSV and Parquet."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from afmsim.runio import replace_atomically
from afmsim.sweep.spec import Run

__all__ = ["read_rows", "write_tables", "replace_atomically"]


def read_rows(runs_dir, runs: list[Run]) -> pd.DataFrame:
    """One row per run from ``runs_dir/<run_id>.json``, in the order of ``runs``.

    Columns: ``run_id``, the swept parameters, each controller's scores together, then ``e_D`` and
    ``wall_s``. Score columns are floats; a score a run lacks (a
    controller it did not use, a null ``std`` of a single experiment) is NaN. Swept values keep
    their types (numbers, booleans, strings, lists).
    """
    rows = [json.loads((Path(runs_dir) / f"{run.run_id}.json").read_text()) for run in runs]
    table = pd.DataFrame(rows)
    fixed = ["run_id", *dict.fromkeys(path for run in runs for path in run.params)]
    scores = [column for column in table.columns if column not in fixed]
    controllers = list(dict.fromkeys(column.split(".")[0] for column in scores if "." in column))
    scores.sort(key=lambda c: controllers.index(c.split(".")[0]) if "." in c else len(controllers))
    table = table[fixed + scores]
    table[scores] = table[scores].astype(float)
    return table


def _flat(table: pd.DataFrame) -> pd.DataFrame:
    """The table with list- and mapping-valued cells as JSON text (CSV and Parquet hold them alike)."""
    flat = table.copy()
    for column in flat.columns:
        if flat[column].map(lambda v: isinstance(v, (list, dict))).any():
            flat[column] = flat[column].map(lambda v: json.dumps(v) if isinstance(v, (list, dict)) else v)
    return flat


def write_tables(table: pd.DataFrame, out_dir) -> list[Path]:
    """Write ``results.csv`` and ``results.parquet`` into ``out_dir``, each atomically; return their paths.

    List-valued swept parameters (e.g. ``scan.size_um``) are stored as JSON text such as ``[5.0, 5.0]``.
    """
    flat = _flat(table)
    out_dir = Path(out_dir)
    return [replace_atomically(out_dir / "results.csv", lambda tmp: flat.to_csv(tmp, index=False)),
            replace_atomically(out_dir / "results.parquet", lambda tmp: flat.to_parquet(tmp, index=False))]
