"""Figures of the twin: measured vs twin trace/retrace with the residual, shift profiles, loop predictions."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["pair_figure", "loop_figure"]

UM = 1e-6


def _profile(ax, profile, label, style, error=False):
    x = profile.x_m / UM
    if error:
        ax.errorbar(x, profile.shift_m / UM, yerr=profile.stderr_m / UM, fmt=style, label=label, capsize=3)
    else:
        ax.plot(x, profile.shift_m / UM, style, label=label)


def pair_figure(path, arrays: dict, pixel_size_m: float, title: str) -> None:
    """Line cross-section (measured trace/retrace, twin retrace), its residual, and the shift profiles.

    ``arrays``: ``trace``, ``retrace``, ``twin_retrace`` (lines, pixels, m), ``measured_profile``,
    ``twin_profile`` and optionally ``default_profile`` (:class:`~afmsim.twin.shift_profile.ShiftProfile`).
    """
    trace, retrace, twin = arrays["trace"], arrays["retrace"], arrays["twin_retrace"]
    row = trace.shape[0] // 2
    x = (np.arange(trace.shape[1]) + 0.5) * pixel_size_m / UM
    fig, axes = plt.subplots(3, 1, figsize=(9, 10), gridspec_kw={"height_ratios": [2, 1, 2]})
    axes[0].plot(x, trace[row] / 1e-9, "k-", lw=1, label="measured trace")
    axes[0].plot(x, retrace[row] / 1e-9, "C0-", lw=1, label="measured retrace")
    axes[0].plot(x, twin[row] / 1e-9, "C3--", lw=1, label="twin retrace")
    axes[0].set(ylabel="height (nm)", title=f"{title}: line {row}")
    axes[0].legend(fontsize=8)
    axes[1].plot(x, (retrace[row] - twin[row]) / 1e-9, "C3-", lw=1)
    axes[1].set(xlabel="x (µm)", ylabel="measured − twin\nretrace (nm)")
    _profile(axes[2], arrays["measured_profile"], "measured", "ko-", error=True)
    _profile(axes[2], arrays["twin_profile"], "twin", "C3s--")
    if arrays.get("default_profile") is not None:
        _profile(axes[2], arrays["default_profile"], "afmsim default stage", "C7^:")
    axes[2].axhline(0, color="0.7", lw=0.8)
    axes[2].set(xlabel="x (µm)", ylabel="retrace − trace\nfeature position (µm)",
                title="shift profile (median over lines, 8 windows)")
    axes[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def loop_figure(path, t, v, x, predictions: dict, split_index: int, title: str) -> None:
    """Measured loop record vs each model's prediction (``predictions``: label → x (m)); held-out part shaded."""
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    axes[0].axvspan(t[split_index], t[-1], color="0.93", label="held out")
    axes[0].plot(t, x / UM, "k-", lw=1, label="measured")
    held = slice(split_index, None)
    axes[1].plot(v[held], x[held] / UM, "k-", lw=1.2, label="measured (held out)")
    for (label, prediction), style in zip(predictions.items(), ("C3--", "C7:")):
        axes[0].plot(t, prediction / UM, style, lw=1, label=label)
        axes[1].plot(v[held], prediction[held] / UM, style, lw=1, label=label)
    axes[0].set(xlabel="t (s)", ylabel="x (µm)", title=title)
    axes[1].set(xlabel="drive (V)", ylabel="x (µm)", title="held-out part")
    for ax in axes:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
