"""The sweep's summary figure: NSL2 and trace–retrace shift per controller against a swept value."""

from __future__ import annotations

import numbers

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

__all__ = ["summary_figure", "axis_label"]

UM = 1e-6
_UNITS = {"um": "µm", "nm": "nm", "hz": "Hz", "V": "V", "deg": "°", "per_s": "1/s", "s": "s", "m": "m",
          "um_per_V": "µm/V"}


def axis_label(path: str) -> str:
    """``path (unit)`` with the unit read from the field name's suffix (``scan.size_um`` → µm)."""
    field = next((part for part in reversed(path.split(".")) if not part.isdigit()), path)
    unit = next((_UNITS[suffix] for suffix in sorted(_UNITS, key=len, reverse=True) if field.endswith("_" + suffix)), None)
    return f"{path} ({unit})" if unit else path


def _number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _x_values(table: pd.DataFrame, parameters: list[str]):
    """(values, label) of the first numeric swept parameter; a numeric list gives its first element."""
    for path in parameters:
        column = list(table[path])
        if all(_number(v) for v in column):
            return np.asarray(column, dtype=float), axis_label(path)
        if all(isinstance(v, list) and v and all(_number(e) for e in v) for v in column):
            return np.asarray([v[0] for v in column], dtype=float), axis_label(f"{path}.0")
    return None, None


def summary_figure(table: pd.DataFrame, parameters: list[str], *, title: str) -> Figure:
    """NSL2 (mean ± σ over experiments) and trace–retrace x shift (µm) of every controller.

    The x axis is the first numeric swept parameter (log-scaled when it spans 20× or more), else
    the run index. Points are joined by lines when only one parameter is swept.
    """
    controllers = [c.removesuffix(".nsl2_mean") for c in table.columns if c.endswith(".nsl2_mean")]
    x, label = _x_values(table, parameters)
    if x is None:
        x, label = np.arange(len(table), dtype=float), "run (sweep order)"
    order = np.argsort(x, kind="stable")
    joined = len(parameters) == 1
    fig = Figure(figsize=(10, 4.2), constrained_layout=True)
    axes = fig.subplots(1, 2)
    panels = (("nsl2", 1.0, "NSL2 (trace vs retrace, 1)"), ("shift_x_m", UM, "trace–retrace shift x (µm)"))
    for ax, (metric, scale, ylabel) in zip(axes, panels):
        for controller in controllers:
            mean = table.get(f"{controller}.{metric}_mean")
            if mean is None:
                continue
            std = table.get(f"{controller}.{metric}_std", pd.Series(np.nan, index=table.index))
            ax.errorbar(x[order], mean.to_numpy()[order] / scale, yerr=np.nan_to_num(std.to_numpy()[order] / scale),
                        marker="o", linestyle="-" if joined else "none", capsize=3, label=controller)
        if metric == "shift_x_m":
            ax.axhline(0.0, color="0.5", linewidth=0.8)
        ax.set_xlabel(label)
        ax.set_ylabel(ylabel)
        if x.min() > 0 and x.max() / x.min() >= 20:
            ax.set_xscale("log")
        ax.grid(alpha=0.3)
    axes[0].legend(title="controller")
    fig.suptitle(f"sweep {title}: {len(table)} runs")
    return fig
