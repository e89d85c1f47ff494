"""The identification experiment and its reference results (paper §3.2, Tables 1 and 2).

The X axis is driven by a unipolar triangle from rest (1 Hz, 9.1 V amplitude ≈ 100 µm) and its
displacement is read by the capacitive sensor at 1 kS/s. Every inverse model of
:data:`afmsim.hysteresis.MODELS` is fitted on the **first cycle** of a training record (it starts
from the de-energised state, as eq. 4 assumes) and scored on ``experiments`` fresh records (new
sensor-noise draws, each seeded): RMS and maximum of the voltage error
``model.predict(measured displacement) − applied voltage`` over the whole record.
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from afmsim.hysteresis import MODELS
from afmsim.metrics import summarize
from afmsim.paper import TABLE2_MEANS, TABLE2_RATIO
from afmsim.reproducible import single_blas_thread
from afmsim.runio import write_json
from afmsim.stage import HYSTERESIS_MODELS, IdentificationRecord, XYStage, default_stage, identification_experiment

__all__ = ["IdentificationResult", "identify", "plant_law", "table1", "table2", "write_identification", "HYSTERETIC_LAWS",
           "identify_laws", "table2_laws", "write_identification_laws"]

#: The plant laws with hysteresis (:data:`afmsim.stage.HYSTERESIS_MODELS` less ``linear``): the
#: minor-loop laws whose Table 2 :func:`identify_laws` sets side by side.
HYSTERETIC_LAWS = tuple(name for name in HYSTERESIS_MODELS if name != "linear")


@dataclass
class IdentificationResult:
    """Fitted models and their errors over repeated experiments (SI units)."""

    models: dict
    errors: dict                    # name -> {"rms_V": [...], "max_V": [...]}
    fit_seconds: dict               # name -> identification time of the fit, s
    training: IdentificationRecord
    evaluations: list = field(repr=False)
    settings: dict = field(default_factory=dict)


def plant_law(stage: XYStage) -> str:
    """The plant's hysteresis family, as ``HYSTERESIS_MODELS`` names it (``"linear"`` when off)."""
    params = stage.x.params
    if not params.hysteresis_enabled:
        return "linear"
    kind = type(params.hysteresis)
    return next((name for name, cls in HYSTERESIS_MODELS.items() if cls is kind), kind.__name__)


@single_blas_thread
def identify(stage: XYStage | None = None, *, seed: int = 0, experiments: int = 10, amplitude_V: float = 9.1,
             frequency_hz: float = 1.0, sample_rate_hz: float = 1000.0, n_operators: int = 10,
             models=None) -> IdentificationResult:
    """Run the identification experiment, fit every model, score it on fresh experiments."""
    stage = stage or default_stage()
    names = list(models or MODELS)
    streams = np.random.default_rng(seed).spawn(experiments + 1)
    run = dict(amplitude_V=amplitude_V, frequency_hz=frequency_hz, sample_rate_hz=sample_rate_hz, cycles=2)
    training = identification_experiment(stage, streams[0], **run)
    d_fit, v_fit = training.cycle(0)
    fitted, fit_seconds = {}, {}
    for name in names:
        start = time.perf_counter()
        fitted[name] = MODELS[name].fit(d_fit, v_fit, n_operators=n_operators)
        fit_seconds[name] = time.perf_counter() - start
    evaluations = [identification_experiment(stage, rng, **run) for rng in streams[1:]]
    errors = {name: {"rms_V": [], "max_V": []} for name in names}
    for record in evaluations:
        for name, model in fitted.items():
            error = model.predict(record.displacement) - record.voltage
            errors[name]["rms_V"].append(float(np.sqrt(np.mean(error**2))))
            errors[name]["max_V"].append(float(np.max(np.abs(error))))
    settings = dict(seed=seed, experiments=experiments, n_operators=n_operators, plant=plant_law(stage), **run)
    return IdentificationResult(fitted, errors, fit_seconds, training, evaluations, settings)


def identify_laws(laws=HYSTERETIC_LAWS, *, seed: int = 0, **settings) -> dict[str, IdentificationResult]:
    """:func:`identify` on the default stage of each plant law (:data:`HYSTERETIC_LAWS` by default),
    every law with the same ``seed`` and ``settings`` (any other keyword of :func:`identify`), so
    each law's numbers are those of its own single-law run. Returns law → result, in ``laws`` order."""
    from afmsim.stage import default_stage

    laws = list(dict.fromkeys(laws))
    unknown = [law for law in laws if law not in HYSTERESIS_MODELS]
    if unknown or not laws:
        raise ValueError(f"laws must be among {', '.join(HYSTERESIS_MODELS)}, got {', '.join(unknown) or 'none'}")
    return {law: identify(default_stage(law), seed=seed, **settings) for law in laws}


def table1(result: IdentificationResult) -> str:
    """Table 1 analogue: DIAPI widths (µm), slopes ω_af, ω_ab (V/µm) and e_ω (eq. 7)."""
    m = result.models["diapi"]
    lines = ["Table 1 analogue: identified DIAPI parameters",
             f"{'i':>3} {'r (µm)':>8} {'ω_af (V/µm)':>12} {'ω_ab (V/µm)':>12} {'e_ω':>7}"]
    for i, (r, wf, wb, e) in enumerate(zip(m.widths, m.weights_trace, m.weights_retrace, m.asymmetry), 1):
        lines.append(f"{i:>3} {r * 1e6:>8.1f} {wf * 1e-6:>12.4f} {wb * 1e-6:>12.4f} {abs(e):>7.0%}")
    return "\n".join(lines)


def table2(result: IdentificationResult) -> str:
    """Table 2 analogue: RMS and maximum voltage errors per experiment, mean and σ."""
    names = list(result.errors)
    head = f"Table 2 analogue: model voltage errors (V) on fresh experiments, {result.settings.get('plant', '?')} plant"
    cols = " ".join(f"{'RMS ' + n.upper():>11}" for n in names) + "  " + " ".join(f"{'max ' + n.upper():>11}" for n in names)
    lines = [head, f"{'exp':>5} " + cols]
    n_exp = len(result.errors[names[0]]["rms_V"])
    for k in range(n_exp):
        row = " ".join(f"{result.errors[n]['rms_V'][k]:>11.4f}" for n in names) + "  " + \
              " ".join(f"{result.errors[n]['max_V'][k]:>11.4f}" for n in names)
        lines.append(f"{k + 1:>5} " + row)
    for label, stat in (("mean", "mean"), ("σ", "std")):
        row = " ".join(f"{summarize(result.errors[n]['rms_V'])[stat]:>11.4f}" for n in names) + "  " + \
              " ".join(f"{summarize(result.errors[n]['max_V'])[stat]:>11.4f}" for n in names)
        lines.append(f"{label:>5} " + row)
    paper = " ".join(f"{TABLE2_MEANS.get(n, {}).get('rms_V', float('nan')):>11.3f}" for n in names) + "  " + \
            " ".join(f"{TABLE2_MEANS.get(n, {}).get('max_V', float('nan')):>11.3f}" for n in names)
    lines.append(f"{'paper':>5} " + paper.replace("nan", "  -"))
    if "spi" in names and "diapi" in names:
        ratio = summarize(result.errors["diapi"]["rms_V"])["mean"] / summarize(result.errors["spi"]["rms_V"])["mean"]
        lines.append(f"DIAPI/SPI mean RMS ratio: {ratio:.2f} (paper {TABLE2_RATIO:.2f}; the plant's skew is calibrated "
                     "to Table 2's SPI error, see docs/reference-results.md)")
    return "\n".join(lines)


def table2_laws(results: dict) -> str:
    """Table 2 analogue with a column block per plant law (``results``: law → result of
    :func:`identify_laws`): per experiment the RMS and maximum voltage error (V) of every model, then
    mean, σ and the paper's means, and each law's DIAPI/SPI mean RMS ratio."""
    laws = list(results)
    names = list(results[laws[0]].errors)
    cols = [(law, stat, name) for law in laws for stat in ("rms_V", "max_V") for name in names]
    cell = 9  # characters per number; a law's block is its 2 × len(names) cells
    block = 2 * len(names) * (cell + 1) - 1
    seeds = {r.settings.get("seed") for r in results.values()}
    lines = [f"Table 2 analogue: model voltage errors (V) on fresh experiments, per plant law (seed "
             f"{', '.join(map(str, seeds))})",
             "      " + " ".join(f"{law + ' plant':-^{block}}" for law in laws),
             f"{'exp':>5} " + " ".join(f"{('RMS ' if s == 'rms_V' else 'max ') + n.upper():>{cell}}" for _, s, n in cols)]

    def row(label, values):
        return f"{label:>5} " + " ".join(f"{v:>{cell}.4f}" if v is not None else f"{'-':>{cell}}" for v in values)

    for k in range(len(results[laws[0]].errors[names[0]]["rms_V"])):
        lines.append(row(str(k + 1), [results[law].errors[n][s][k] for law, s, n in cols]))
    for label, stat in (("mean", "mean"), ("σ", "std")):
        lines.append(row(label, [summarize(results[law].errors[n][s])[stat] for law, s, n in cols]))
    lines.append(row("paper", [TABLE2_MEANS.get(n, {}).get(s) for _, s, n in cols]))
    if "spi" in names and "diapi" in names:
        ratios = {law: summarize(r.errors["diapi"]["rms_V"])["mean"] / summarize(r.errors["spi"]["rms_V"])["mean"]
                  for law, r in results.items()}
        lines.append("DIAPI/SPI mean RMS ratio: " + ", ".join(f"{law} {v:.2f}" for law, v in ratios.items())
                     + f" (paper {TABLE2_RATIO:.2f}; each plant's skew is calibrated to Table 2's SPI error, "
                       "see docs/reference-results.md)")
    return "\n".join(lines)


def summary_dict(result: IdentificationResult) -> dict:
    """The content of ``identify.json``."""
    models = {}
    for name, model in result.models.items():
        models[name] = {stat: summarize(result.errors[name][stat]) for stat in ("rms_V", "max_V")}
        models[name]["params"] = model.params()
        models[name]["fit_seconds"] = result.fit_seconds[name]
    out = {"settings": result.settings, "models": models, "paper_table2": TABLE2_MEANS}
    if "spi" in models and "diapi" in models:
        out["diapi_over_spi_rms"] = models["diapi"]["rms_V"]["mean"] / models["spi"]["rms_V"]["mean"]
    return out


def write_identification(result: IdentificationResult, folder) -> None:
    """Write ``identify.json``, ``tables.txt`` and ``loops.csv`` (first evaluation record with
    every model's predicted voltage) into ``folder``, plus the paper analogues:
    ``fig6_loops.png`` (measured vs SPI / DIAPI / CAPI loops), ``fig7_errors.png`` (trace and
    retrace voltage errors vs displacement), ``table2.md``/``table2.csv`` (with the paper's
    column) and ``table1.csv`` (DIAPI parameters, when DIAPI was fitted)."""
    from afmsim.report.identification_report import write_identification_report

    folder = Path(folder)
    write_identification_report(result, folder)
    write_json(folder / "identify.json", summary_dict(result))
    (folder / "tables.txt").write_text(table1(result) + "\n\n" + table2(result) + "\n")
    record = result.evaluations[0]
    predictions = {name: model.predict(record.displacement) for name, model in result.models.items()}
    with open(folder / "loops.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["t_s", "voltage_V", "displacement_m", *[f"{n}_voltage_V" for n in predictions]])
        for k in range(record.t.size):
            writer.writerow([f"{record.t[k]:.6g}", f"{record.voltage[k]:.6g}", f"{record.displacement[k]:.6g}",
                             *[f"{p[k]:.6g}" for p in predictions.values()]])


def write_identification_laws(results: dict, folder) -> None:
    """Write :func:`identify_laws`'s results into ``folder``: each law's own outputs
    (:func:`write_identification`) in ``folder/<law>/``, and at the top ``identify.json`` (one
    entry per law under ``"laws"``), ``tables.txt`` (:func:`table2_laws`) and
    ``table2.md``/``table2.csv`` with a column block per law."""
    from afmsim.report.tables import identification_table2_laws

    folder = Path(folder)
    for law, result in results.items():
        (folder / law).mkdir(exist_ok=True)
        write_identification(result, folder / law)
    write_json(folder / "identify.json", {"laws": {law: summary_dict(r) for law, r in results.items()},
                                          "paper_table2": TABLE2_MEANS})
    (folder / "tables.txt").write_text(table2_laws(results) + "\n")
    md, csv_text = identification_table2_laws(results)
    (folder / "table2.md").write_text(md)
    (folder / "table2.csv").write_text(csv_text)
