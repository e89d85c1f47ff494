"""Matplotlib analogues of the paper's figures.

* :func:`plot_scan_figure` — Fig. 10–13: (a) trace, (b) retrace, (c) trace − retrace, (d) the
  cross-section through the central micro-lens (trace vs retrace) or, for a grating, the
  row-averaged profile across the lines, (e) its magnified part where trace and retrace differ most.
* :func:`plot_binarized` — the binarized trace/retrace images that NSL2 (eq. 8) compares, overlaid.
* :func:`plot_identification_loops` / :func:`plot_identification_errors` — Fig. 6 / Fig. 7:
  measured loop vs model loops, and trace/retrace voltage errors vs displacement.
* :func:`plot_time_saving` — Fig. 8: DIAPI vs IIAPI identification time saving over M and N.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from afmsim.metrics import lens_centres  # noqa: E402
from afmsim.metrics.nsl2 import binarize, nsl2  # noqa: E402
from afmsim.paper import FIG8  # noqa: E402
from afmsim.samples.heightmap import HeightMap  # noqa: E402

from .figures import (  # noqa: E402
    ColourScale,
    above_substrate,
    FIXED_TITLES,
    difference_cmap,
    fixed_title_height,
    height_extent_um,
    run_colour_scales,
    show_height,
)

__all__ = ["ScanFigure", "plot_scan_figure", "plot_scan_figures", "plot_binarized", "binarized_overlay", "plot_identification_loops", "plot_identification_errors",
           "plot_time_saving", "central_lens"]

UM, NM = 1e-6, 1e-9
_DPI = 110


def central_lens(image: HeightMap):
    """(x, y) in metres of the lens nearest the image centre, or None when none is found."""
    try:
        centres = lens_centres(image.z, image.pixel_size, origin=image.origin)
    except ValueError:
        return None
    if len(centres) == 0:
        return None
    middle = np.array([image.x.mean(), image.y.mean()])
    return centres[np.argmin(np.linalg.norm(centres - middle, axis=1))]


class ScanFigure:
    """One controller's scan, Fig. 10–13 analogue: (a) trace, (b) retrace, (c) trace − retrace,
    (d) a cross-section, (e) its zoom — built once per run grid and redrawn for each controller.

    (a)/(b): heights above the substrate on the run's colour scale (``scale``, see
    :mod:`afmsim.report.figures`), equal panels sharing axes. (c) trace − retrace (raw heights,
    nm) on the run's symmetric difference scale: what a perfect stage leaves as noise and
    hysteresis as a red/blue pair on each feature edge. (d) Micro-lenses (and other samples): the
    scan line through the central lens of the trace image (white cross; its trace position is
    shown dashed on the retrace, as in Fig. 10), trace vs retrace heights; gratings: the profile
    averaged over all lines. (e) The part of (d) in the grey box, around the largest
    trace/retrace difference (paper Figs. 11–13's magnified view), in its own panel so that it
    hides nothing.

    The axes, colour bars and their tick objects are made once (``grid``: any image of the run;
    every image of a run shares its pixel grid) and :meth:`draw` replaces only what depends on
    the controller's images: a redraw costs about half a first draw. Use as a context manager
    (the figure is closed on exit).
    """

    def __init__(self, grid: HeightMap, *, kind: str, scale: ColourScale):
        self.kind, self.grid = kind, grid
        with plt.rc_context(FIXED_TITLES):
            self.fig = fig = plt.figure(figsize=(15, 9.4))
            # Fixed grids (faster than a layout engine): the three maps and their bars above, the
            # cross-section and its zoom below; the narrow columns are gaps for the labels beside them.
            top = fig.add_gridspec(1, 6, width_ratios=[1, 1, 0.05, 0.3, 1, 0.05], left=0.055, right=0.95,
                                   bottom=0.53, top=0.905, wspace=0.08)
            bottom = fig.add_gridspec(1, 3, width_ratios=[1.6, 0.12, 1], left=0.055, right=0.95, bottom=0.065,
                                      top=0.43, wspace=0.08)
            self.ax_a = fig.add_subplot(top[0])
            self.ax_b = fig.add_subplot(top[1], sharex=self.ax_a, sharey=self.ax_a)
            self.ax_c = fig.add_subplot(top[4], sharex=self.ax_a, sharey=self.ax_a)
            self.ax, self.ax_zoom = fig.add_subplot(bottom[0]), fig.add_subplot(bottom[2])
        blank = np.zeros(grid.shape)
        self.maps = []
        for a, label in zip((self.ax_a, self.ax_b), ("(a) trace (left → right)", "(b) retrace (right → left)")):
            self.maps.append(show_height(a, replace(grid, z=blank), scale.height_nm))
            a.set_title(label)
        self.ax_a.set_ylabel("y (µm)")
        for a in (self.ax_b, self.ax_c):
            a.tick_params(labelleft=False)
        fig.colorbar(self.maps[0], cax=fig.add_subplot(top[2]), label="height above substrate (nm)",
                     extend=scale.height_extend)
        lim = scale.difference_nm
        self.difference = self.ax_c.imshow(blank, origin="lower", extent=height_extent_um(grid), cmap=difference_cmap(),
                                           vmin=-lim, vmax=lim, interpolation="nearest")
        self.ax_c.set_title("(c) trace − retrace (mismatch)")
        self.ax_c.set_xlabel("x (µm)")
        fig.colorbar(self.difference, cax=fig.add_subplot(top[5]), label="trace − retrace (nm)",
                     extend=scale.difference_extend)
        for target in (self.ax, self.ax_zoom):
            target.set_xlabel("x (µm)")
            target.grid(alpha=0.3)
        self.ax.set_ylabel("height above substrate (nm)")
        self._drawn: list = []  # the artists of the last controller, removed before the next

    def __enter__(self):
        return self

    def __exit__(self, *_):
        plt.close(self.fig)

    def draw(self, trace: HeightMap, retrace: HeightMap, path, *, title: str) -> Path:
        """Draw one controller's trace/retrace pair and save the figure as ``path`` (PNG)."""
        if trace.shape != self.grid.shape or retrace.shape != self.grid.shape:
            raise ValueError(f"images {trace.shape}/{retrace.shape} do not match the figure's grid {self.grid.shape}")
        for artist in self._drawn:
            artist.remove()
        self._drawn = []
        self.ax.relim()
        with plt.rc_context(FIXED_TITLES):
            self._draw(trace, retrace, title)
            path = Path(path)
            self.fig.savefig(path, dpi=_DPI)
        return path

    def _draw(self, trace, retrace, title):
        keep = self._drawn.append
        centre_t = central_lens(trace) if self.kind != "grating" else None
        centre_r = central_lens(retrace) if self.kind != "grating" else None
        for shown, image in zip(self.maps, (trace, retrace)):
            shown.set_data(above_substrate(image).z / NM)
        self.difference.set_data((trace.z - retrace.z) / NM)
        cross = dict(marker="+", markersize=16, color="white", linestyle="none")
        if centre_t is not None:
            keep(self.ax_a.plot(centre_t[0] / UM, centre_t[1] / UM, markeredgewidth=1.6, **cross)[0])
            keep(self.ax_b.plot(centre_t[0] / UM, centre_t[1] / UM, markeredgewidth=1.2, alpha=0.6, **cross)[0])
            keep(self.ax_b.axvline(centre_t[0] / UM, color="white", linestyle="--", linewidth=0.8, alpha=0.7))
        if centre_r is not None:
            keep(self.ax_b.plot(centre_r[0] / UM, centre_r[1] / UM, markeredgewidth=1.6, **cross)[0])

        ax, ax_zoom = self.ax, self.ax_zoom
        x_um = trace.x / UM
        t_prof, r_prof = above_substrate(trace).z, above_substrate(retrace).z
        if self.kind == "grating":
            t_prof, r_prof = t_prof.mean(axis=0), r_prof.mean(axis=0)
            ax.set_title("(d) profile averaged over all lines")
        else:
            y0 = centre_t[1] if centre_t is not None else trace.y.mean()
            row = int(np.clip(np.rint((y0 - trace.origin[1]) / trace.pixel_size[1]), 0, trace.shape[0] - 1))
            t_prof, r_prof = t_prof[row], r_prof[row]
            what = "central lens" if centre_t is not None else "image centre"
            ax.set_title(f"(d) line through the {what}, y = {trace.y[row] / UM:.2f} µm")
            for a in (self.ax_a, self.ax_b):
                keep(a.axhline(trace.y[row] / UM, color="cyan", linewidth=0.8, alpha=0.8))
        profiles = [(target.plot(x_um, t_prof / NM, "-", color="tab:blue", label="trace (T)")[0],
                     target.plot(x_um, r_prof / NM, "--", color="tab:red", label="retrace (R)")[0])
                    for target in (ax, ax_zoom)]
        self._drawn += [line for pair in profiles for line in pair]
        if centre_t is not None:
            keep(ax.axvline(centre_t[0] / UM, color="tab:blue", linewidth=0.7, alpha=0.5))
        if centre_r is not None:
            keep(ax.axvline(centre_r[0] / UM, color="tab:red", linewidth=0.7, alpha=0.5, linestyle="--"))
        ax.autoscale_view()
        keep(ax.legend(handles=list(profiles[0]), loc="best", fontsize=8))
        k = int(np.argmax(np.abs(t_prof - r_prof)))
        half = max(2, len(x_um) // 16)
        lo_i, hi_i = max(0, k - half), min(len(x_um) - 1, k + half)
        window = np.concatenate([t_prof[lo_i:hi_i + 1], r_prof[lo_i:hi_i + 1]]) / NM
        pad = max(0.05 * np.ptp(window), 0.5)
        ax_zoom.set_xlim(x_um[lo_i], x_um[hi_i])
        ax_zoom.set_ylim(window.min() - pad, window.max() + pad)
        ax_zoom.set_title(f"(e) zoom: |T − R| up to {abs(t_prof[k] - r_prof[k]) / NM:.0f} nm")
        keep(ax.add_patch(plt.Rectangle((x_um[lo_i], window.min() - pad), x_um[hi_i] - x_um[lo_i],
                                        np.ptp(window) + 2 * pad, fill=False, edgecolor="0.35", linewidth=1.0)))
        self.fig.suptitle(title)


def plot_scan_figure(trace: HeightMap, retrace: HeightMap, path, *, kind: str, title: str,
                     scale: ColourScale | None = None) -> Path:
    """One controller's :class:`ScanFigure` (``scale``: the run's colour scales; by default this
    pair's own), saved as ``path``."""
    with ScanFigure(trace, kind=kind, scale=scale or run_colour_scales({"": (trace, retrace)})) as figure:
        return figure.draw(trace, retrace, path, title=title)


def plot_scan_figures(pairs: dict, folder, *, kind: str, title: str, scale: ColourScale) -> list[Path]:
    """``figure_<controller>.png`` in ``folder`` for every ``{controller: (trace, retrace)}`` of one
    run, one :class:`ScanFigure` redrawn for each; ``title`` is formatted with ``controller``."""
    if not pairs:
        return []
    first = next(iter(pairs.values()))[0]
    with ScanFigure(first, kind=kind, scale=scale) as figure:
        return [figure.draw(trace, retrace, Path(folder) / f"figure_{name}.png", title=title.format(controller=name))
                for name, (trace, retrace) in pairs.items()]


#: Colours of :func:`plot_binarized`: (trace, retrace) binarized values → RGB.
BINARIZED_COLOURS = {(0, 0): (0.0, 0.0, 0.0), (1, 1): (1.0, 1.0, 1.0), (1, 0): (0.85, 0.1, 0.1), (0, 1): (0.15, 0.45, 1.0)}


def binarized_overlay(trace: np.ndarray, retrace: np.ndarray) -> np.ndarray:
    """RGB image (lines, pixels, 3) of two binarized images: black where both are below their
    mean, white where both are above, red where only the trace is, blue where only the retrace is."""
    bt, br = binarize(trace).astype(int), binarize(retrace).astype(int)
    rgb = np.empty(bt.shape + (3,))
    for (t, r), colour in BINARIZED_COLOURS.items():
        rgb[(bt == t) & (br == r)] = colour
    return rgb


@fixed_title_height
def plot_binarized(images: dict, path, *, title: str) -> Path:
    """What NSL2 (eq. 8) compares, one panel per controller: trace and retrace binarized at their
    own mean height, overlaid (:func:`binarized_overlay`: red = above the mean in the trace only,
    blue = in the retrace only — the pixels NSL2 counts); NSL2 in the panel title. ``images``:
    controller → (trace, retrace)."""
    n = len(images)
    columns = min(n, 4)
    rows = -(-n // columns)
    height = 3.3 * rows + 0.9
    fig, axes = plt.subplots(rows, columns, figsize=(3.2 * columns + 0.6, height), squeeze=False, sharex=True,
                             sharey=True)
    # Fixed margins in inches (the suptitle and the key above the first row's titles).
    fig.subplots_adjust(left=0.6 / (3.2 * columns + 0.6), right=0.98, bottom=0.5 / height, top=1 - 0.85 / height,
                        wspace=0.12, hspace=0.35)
    for ax, (name, (trace, retrace)) in zip(axes.ravel(), images.items()):
        try:
            score = f"NSL2 = {nsl2(binarize(trace.z), binarize(retrace.z)):,.0f}"
        except ValueError:
            score = "NSL2 undefined"
        ax.imshow(binarized_overlay(trace.z, retrace.z), origin="lower", extent=height_extent_um(trace),
                  interpolation="nearest")
        ax.set_title(f"{name}: {score}", fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel("y (µm)", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("x (µm)", fontsize=8)
    fig.suptitle(title)
    fig.text(0.5, 1 - 0.55 / height, "white: above the mean in both · black: below in both · red: trace only · "
             "blue: retrace only (the pixels NSL2 counts)", ha="center", fontsize=8)
    path = Path(path)
    fig.savefig(path, dpi=_DPI)
    plt.close(fig)
    return path


# --------------------------------------------------------------------------- identification

_MODEL_STYLE = {"spi": ("tab:orange", "SPI"), "diapi": ("tab:green", "DIAPI"), "capi": ("tab:purple", "CAPI"),
                "iiapi": ("tab:brown", "IIAPI")}
LOOP_MODELS = ("spi", "diapi", "capi")


def _branches(record, cycle: int = 0):
    """Index arrays of the trace (rising voltage) and retrace (falling) branches of one cycle."""
    n = record.samples_per_cycle
    sl = np.arange(cycle * n, min((cycle + 1) * n + 1, record.t.size))
    dv = np.gradient(record.voltage)[sl]
    return sl[dv > 0], sl[dv <= 0]


def plot_identification_loops(result, path) -> Path:
    """Fig. 6 analogue: measured hysteresis loop and the SPI / DIAPI / CAPI model loops
    (drive voltage vs displacement, µm) on the first evaluation record, first cycle."""
    record = result.evaluations[0]
    n = record.samples_per_cycle
    sl = slice(0, n + 1)
    d_um = record.displacement[sl] / UM
    fig, ax = plt.subplots(figsize=(7, 5.2))
    fig.subplots_adjust(left=0.11, right=0.97, bottom=0.11, top=0.92)
    ax.plot(d_um, record.voltage[sl], "-", color="black", linewidth=2.2, label="actual (measured)")
    for name in LOOP_MODELS:
        if name in result.models:
            colour, label = _MODEL_STYLE[name]
            v = result.models[name].predict(record.displacement)[sl]
            ax.plot(d_um, v, "--", color=colour, linewidth=1.2, label=f"{label} model")
    ax.set_xlabel("displacement (µm)")
    ax.set_ylabel("voltage (V)")
    ax.set_title("Fig. 6 analogue: actual hysteresis loop and inverse PI model loops")
    ax.legend()
    ax.grid(alpha=0.3)
    path = Path(path)
    fig.savefig(path, dpi=_DPI)
    plt.close(fig)
    return path


def plot_identification_errors(result, path, *, n_records: int = 3) -> Path:
    """Fig. 7 analogue: (a) trace and (b) retrace voltage errors (model − applied) vs displacement
    of SPI / DIAPI / CAPI on up to ``n_records`` evaluation records (first cycle each)."""
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.8), sharey=True)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.12, top=0.86, wspace=0.08)
    styles = ["-", "--", ":"]
    for j, record in enumerate(result.evaluations[:n_records]):
        trace_idx, retrace_idx = _branches(record)
        for name in LOOP_MODELS:
            if name not in result.models:
                continue
            colour, label = _MODEL_STYLE[name]
            error = result.models[name].predict(record.displacement) - record.voltage
            for ax, idx, prefix in zip(axes, (trace_idx, retrace_idx), ("T", "R")):
                ax.plot(record.displacement[idx] / UM, error[idx], styles[j % 3], color=colour, linewidth=0.9,
                        label=f"{prefix}-{label}" if j == 0 else None)
    for ax, what in zip(axes, ("(a) trace (rising voltage)", "(b) retrace (falling voltage)")):
        ax.axhline(0, color="black", linewidth=0.6)
        ax.set_title(f"{what}, {min(n_records, len(result.evaluations))} experiments")
        ax.set_xlabel("displacement (µm)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("voltage error (V)")
    fig.suptitle("Fig. 7 analogue: model voltage errors vs displacement")
    path = Path(path)
    fig.savefig(path, dpi=_DPI)
    plt.close(fig)
    return path


# --------------------------------------------------------------------------- Fig. 8


def plot_time_saving(json_path, png_path) -> Path:
    """Fig. 8 analogue from ``benchmarks/results/identification_timing.json``: time saving (%)
    of DIAPI over IIAPI identification (a) vs operator count N per sampling M and (b) vs M per N
    (skipped (M, N) combinations are left out)."""
    data = json.loads(Path(json_path).read_text())
    rows = [r for r in data["rows"] if "time_saving_percent" in r]
    if not rows:
        raise ValueError(f"{json_path}: no timed rows")
    ms = sorted({r["M"] for r in rows})
    ns = sorted({r["N"] for r in rows})
    table = {(r["M"], r["N"]): r["time_saving_percent"] for r in rows}
    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(12, 4.6), sharey=True)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.12, top=0.86, wspace=0.08)
    cmap = plt.get_cmap("viridis")
    for i, m in enumerate(ms):
        pts = [(n, table[m, n]) for n in ns if (m, n) in table]
        if pts:
            ax_a.plot(*zip(*pts), "o-", color=cmap(i / max(1, len(ms) - 1)), label=f"M = {m}")
    for i, n in enumerate(ns):
        pts = [(m, table[m, n]) for m in ms if (m, n) in table]
        if pts:
            ax_b.plot(*zip(*pts), "s-", color=cmap(i / max(1, len(ns) - 1)), label=f"N = {n}")
    mean_by_m = [(m, float(np.mean([table[m, n] for n in ns if (m, n) in table]))) for m in ms]
    ax_b.plot(*zip(*mean_by_m), "k--", linewidth=1.5, label="mean over N")
    paper_m, paper_percent = FIG8["M"], 100 * FIG8["saving_fraction_at_M200"]
    ax_b.plot([paper_m], [paper_percent], "*", color="tab:red", markersize=14,
              label=f"paper: ≈ {paper_percent:.0f} % at M = {paper_m}")
    ax_b.set_xscale("log")
    ax_a.set_xlabel("operator quantity N")
    ax_b.set_xlabel("samples per hysteresis loop M")
    ax_a.set_ylabel("time saving of DIAPI over IIAPI (%)")
    ax_a.set_title("(a) vs N")
    ax_b.set_title("(b) vs M")
    for ax in (ax_a, ax_b):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    fig.suptitle(f"Fig. 8 analogue ({data.get('statistic', 'median')} of {data.get('repeats', '?')} runs)")
    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png_path, dpi=_DPI)
    plt.close(fig)
    return png_path
