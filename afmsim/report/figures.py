"""Matplotlib figures of a run: trace/retrace height images with µm axes and an nm colour bar."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from afmsim.samples.heightmap import HeightMap  # noqa: E402

__all__ = ["plot_trace_retrace", "height_extent_um"]

UM, NM = 1e-6, 1e-9


def height_extent_um(hmap: HeightMap) -> list[float]:
    """imshow extent (left, right, bottom, top) of a map's pixel edges, in µm."""
    dx, dy = hmap.pixel_size
    return [(hmap.x[0] - dx / 2) / UM, (hmap.x[-1] + dx / 2) / UM, (hmap.y[0] - dy / 2) / UM, (hmap.y[-1] + dy / 2) / UM]


def plot_trace_retrace(trace: HeightMap, retrace: HeightMap, path, *, title: str) -> Path:
    """Trace and retrace side by side on one height scale (nm, minimum at 0), axes in µm."""
    base = min(trace.z.min(), retrace.z.min())
    vmax = (max(trace.z.max(), retrace.z.max()) - base) / NM
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6), constrained_layout=True)
    for ax, image, label in zip(axes, (trace, retrace), ("trace (left → right)", "retrace (right → left)")):
        shown = ax.imshow((image.z - base) / NM, origin="lower", extent=height_extent_um(image), cmap="afmhot",
                          vmin=0.0, vmax=vmax, interpolation="nearest")
        ax.set_title(label)
        ax.set_xlabel("x (µm)")
        ax.set_ylabel("y (µm)")
    fig.colorbar(shown, ax=axes, label="height (nm)", shrink=0.9)
    fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
