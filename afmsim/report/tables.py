"""Paper-table analogues as Markdown and CSV.

* :func:`nsl2_table` — Table 3 (micro-lens) / Table 4 (grating) analogue: NSL2 (eq. 8) between
  trace and retrace per experiment and controller, mean, σ, e_D (eq. 9), with the paper's means
  beside afmsim's. Controller → paper column: none → D_N, spi → D_S, diapi → D_A, vendor → D_B.
* :func:`identification_table2` / :func:`identification_table1_csv` — Table 2 (model voltage
  errors, with the paper's column) and Table 1 (DIAPI parameters) analogues.

NSL2 grows with the pixel count (D = 2n(1 − r)), so compare ratios with the paper unless the
image size matches the paper's; the tables therefore also give every mean relative to D_A.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from afmsim.paper import TABLE2_MEANS, TABLE2_RATIO, TABLE3, TABLE4

__all__ = ["PAPER_COLUMNS", "PAPER_TABLE3", "PAPER_TABLE4", "paper_nsl2_for", "nsl2_table", "write_nsl2_table",
           "identification_table2", "identification_table2_laws", "identification_table1_csv", "identification_table1_markdown", "TABLE1_COLUMNS",
           "markdown_table"]

#: afmsim controller → the paper's NSL2 column.
PAPER_COLUMNS = {"none": "D_N", "spi": "D_S", "diapi": "D_A", "vendor": "D_B"}
_COLUMN_LABEL = {"D_N": "without calibration", "D_S": "SPI model", "D_A": "DIAPI model", "D_B": "Bruker AFM"}

#: Paper Table 3 (micro-lens) and Table 4 (silicon grating) means; e_D as a fraction.
PAPER_TABLE3, PAPER_TABLE4 = TABLE3, TABLE4


def paper_nsl2_for(kind: str) -> tuple[str, dict]:
    """(label, values) of the paper table matching a sample kind (gratings: Table 4, else Table 3)."""
    if kind == "grating":
        return "Table 4 (silicon grating)", PAPER_TABLE4
    return "Table 3 (micro-lens)", PAPER_TABLE3


def _fmt(v, spec=",.0f") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return format(v, spec)


def _pct(v) -> str:
    return "–" if v is None or not math.isfinite(v) else f"{100 * v:.1f} %"


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    """A GitHub-flavoured Markdown table (first column left-aligned, others right-aligned)."""
    out = ["| " + " | ".join(header) + " |", "|" + "|".join([":---"] + ["---:"] * (len(header) - 1)) + "|"]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out)


def _e_d(spi, diapi):
    if spi is None or diapi is None or not spi:
        return None
    return (spi - diapi) / spi


def nsl2_table(metrics: dict, kind: str) -> dict:
    """The Table 3/4 analogue from a run's ``metrics.json`` content.

    Returns a dict with ``title``, ``controllers``, ``per_experiment`` (list of
    ``{controller: D}`` with ``e_D``), ``mean``/``std`` per controller, ``e_D`` (of the means,
    as the paper's), ``paper`` (label and means) — the inputs of :func:`write_nsl2_table`.
    """
    label, paper = paper_nsl2_for(kind)
    controllers = list(metrics["controllers"])
    per = {c: list(metrics["controllers"][c]["nsl2"]["per_experiment"]) for c in controllers}
    n = max((len(v) for v in per.values()), default=0)
    rows = []
    for k in range(n):
        row = {c: (per[c][k] if k < len(per[c]) else None) for c in controllers}
        row["e_D"] = _e_d(row.get("spi"), row.get("diapi"))
        rows.append(row)
    mean = {c: float(np.mean(per[c])) for c in controllers}
    std = {c: float(np.std(per[c], ddof=1)) if len(per[c]) > 1 else None for c in controllers}
    return {"title": f"{label} analogue: NSL2 between trace and retrace images", "kind": kind,
            "controllers": controllers, "per_experiment": rows, "mean": mean, "std": std,
            "e_D": _e_d(mean.get("spi"), mean.get("diapi")), "paper_label": label, "paper": paper}


def _table_header(t) -> list[str]:
    cols = []
    for c in t["controllers"]:
        col = PAPER_COLUMNS.get(c)
        cols.append(f"{c} ({col})" if col else c)
    return ["experiment", *cols, "e_D"]


def nsl2_markdown(t: dict) -> str:
    """Markdown of the table: per-experiment rows, mean, σ, and a paper-vs-afmsim summary."""
    header = _table_header(t)
    rows = [[str(k + 1), *[_fmt(r[c]) for c in t["controllers"]], _pct(r["e_D"])]
            for k, r in enumerate(t["per_experiment"])]
    rows.append(["**mean**", *[_fmt(t["mean"][c]) for c in t["controllers"]], _pct(t["e_D"])])
    rows.append(["σ", *[_fmt(t["std"][c], ",.1f") for c in t["controllers"]], ""])
    paper = t["paper"]
    rows.append([f"paper mean ({t['paper_label']})",
                 *[_fmt(paper.get(PAPER_COLUMNS.get(c, ""), None)) for c in t["controllers"]],
                 _pct(paper["e_D"])])
    parts = [f"**{t['title']}**", "", markdown_table(header, rows), ""]
    # Paper column beside afmsim's, with ratios to D_A (NSL2 scales with the pixel count).
    a_ours, a_paper = t["mean"].get("diapi"), paper["D_A"]
    srows = []
    for c in t["controllers"]:
        col = PAPER_COLUMNS.get(c)
        p = paper.get(col) if col else None
        srows.append([f"{c}" + (f" → {col} ({_COLUMN_LABEL[col]})" if col else " (no paper column)"),
                      _fmt(p), _fmt(t["mean"][c]), _fmt(t["std"][c], ",.1f"),
                      _fmt(p / a_paper if p else None, ".2f"),
                      _fmt(t["mean"][c] / a_ours if a_ours else None, ".2f")])
    srows.append(["e_D = (D_S − D_A)/D_S", _pct(paper["e_D"]), _pct(t["e_D"]), "", "", ""])
    parts += [markdown_table(["quantity", "paper mean", "afmsim mean", "afmsim σ", "paper / D_A", "afmsim / D_A"],
                             srows)]
    return "\n".join(parts) + "\n"


def nsl2_csv(t: dict) -> str:
    """CSV: one row per experiment, then ``mean``, ``std`` and ``paper`` rows."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["experiment", *t["controllers"], "e_D"])
    num = lambda v: "" if v is None else f"{v:.6g}"  # noqa: E731
    for k, r in enumerate(t["per_experiment"]):
        w.writerow([k + 1, *[num(r[c]) for c in t["controllers"]], num(r["e_D"])])
    w.writerow(["mean", *[num(t["mean"][c]) for c in t["controllers"]], num(t["e_D"])])
    w.writerow(["std", *[num(t["std"][c]) for c in t["controllers"]], ""])
    w.writerow(["paper", *[num(t["paper"].get(PAPER_COLUMNS.get(c, ""), None)) for c in t["controllers"]],
                num(t["paper"]["e_D"])])
    return buf.getvalue()


def write_nsl2_table(metrics: dict, kind: str, folder) -> tuple[dict, list[Path]]:
    """Write ``nsl2_table.md`` and ``nsl2_table.csv``; returns the table dict and the paths."""
    folder = Path(folder)
    t = nsl2_table(metrics, kind)
    md, cs = folder / "nsl2_table.md", folder / "nsl2_table.csv"
    md.write_text(nsl2_markdown(t))
    cs.write_text(nsl2_csv(t))
    return t, [md, cs]


# --------------------------------------------------------------------------- identification


def _error_rows(writer, series: list, paper: list) -> list[list[str]]:
    """Write the per-experiment, mean, σ and paper rows of a Table 2 analogue to the CSV ``writer``
    (one column per list of per-experiment errors in ``series``; ``paper``: the paper's mean per
    column or None) and return the same rows for the markdown table."""
    from afmsim.metrics import summarize

    rows_md = []
    for k in range(len(series[0])):
        vals = [values[k] for values in series]
        writer.writerow([k + 1, *[f"{v:.6g}" for v in vals]])
        rows_md.append([str(k + 1), *[f"{v:.4f}" for v in vals]])
    for label, stat in (("mean", "mean"), ("std", "std")):
        vals = [summarize(values)[stat] for values in series]
        writer.writerow([label, *[f"{v:.6g}" for v in vals]])
        rows_md.append([f"**{label}**" if label == "mean" else "σ", *[_fmt(v, ".4f") for v in vals]])
    writer.writerow(["paper", *["" if v is None else f"{v:.6g}" for v in paper]])
    rows_md.append(["paper mean", *[_fmt(v, ".3f") for v in paper]])
    return rows_md


def identification_table2(result) -> tuple[str, str]:
    """Table 2 analogue (RMS and max voltage error, V) as ``(markdown, csv)`` with the paper's column."""
    from afmsim.metrics import summarize

    names = list(result.errors)
    stats = [("rms_V", "RMS"), ("max_V", "max")]
    cols = [(n, s, lab) for s, lab in stats for n in names]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["experiment", *[f"{s}_{n}" for n, s, _ in cols]])
    rows_md = _error_rows(w, [result.errors[n][s] for n, s, _ in cols],
                          [TABLE2_MEANS.get(n, {}).get(s) for n, s, _ in cols])
    md = ["**Table 2 analogue: model voltage errors (V) on fresh experiments**", "",
          markdown_table(["experiment", *[f"{lab} {n.upper()}" for n, _, lab in cols]], rows_md), ""]
    srows = []
    for n in names:
        r, m = summarize(result.errors[n]["rms_V"]), summarize(result.errors[n]["max_V"])
        p = TABLE2_MEANS.get(n, {})
        srows.append([n.upper(), _fmt(p.get("rms_V"), ".3f"), _fmt(r["mean"], ".4f"), _fmt(r["std"], ".4f"),
                      _fmt(p.get("max_V"), ".3f"), _fmt(m["mean"], ".4f")])
    md.append(markdown_table(["model", "paper RMS", "afmsim RMS", "afmsim σ", "paper max", "afmsim max"], srows))
    if "spi" in names and "diapi" in names:
        ratio = summarize(result.errors["diapi"]["rms_V"])["mean"] / summarize(result.errors["spi"]["rms_V"])["mean"]
        md += ["", f"DIAPI/SPI mean RMS ratio: {ratio:.2f} (paper {TABLE2_RATIO:.2f})"]
    return "\n".join(md) + "\n", buf.getvalue()


def identification_table2_laws(results: dict) -> tuple[str, str]:
    """Table 2 analogue with a column block per plant law (``results``: law → identification result,
    :func:`afmsim.identification.identify_laws`) as ``(markdown, csv)``: per experiment, mean, σ
    and the paper's means, RMS and max error (V) of every model; CSV columns ``<law>_<stat>_<model>``."""
    from afmsim.metrics import summarize

    laws = list(results)
    names = list(results[laws[0]].errors)
    cols = [(law, s, n) for law in laws for s in ("rms_V", "max_V") for n in names]
    label = {"rms_V": "RMS", "max_V": "max"}
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["experiment", *[f"{law}_{s}_{n}" for law, s, n in cols]])
    rows_md = _error_rows(w, [results[law].errors[n][s] for law, s, n in cols],
                          [TABLE2_MEANS.get(n, {}).get(s) for _, s, n in cols])
    md = ["**Table 2 analogue per plant law: model voltage errors (V) on fresh experiments**", "",
          markdown_table(["experiment", *[f"{law}: {label[s]} {n.upper()}" for law, s, n in cols]], rows_md)]
    if "spi" in names and "diapi" in names:
        ratios = [f"{law} {summarize(r.errors['diapi']['rms_V'])['mean'] / summarize(r.errors['spi']['rms_V'])['mean']:.2f}"
                  for law, r in results.items()]
        md += ["", f"DIAPI/SPI mean RMS ratio: {', '.join(ratios)} (paper {TABLE2_RATIO:.2f})"]
    return "\n".join(md) + "\n", buf.getvalue()


#: What Table 1's columns mean (the paper prints them without definitions).
TABLE1_COLUMNS = ("i: operator number; r (µm): its threshold width (eq. 5, spread over the identification data); "
                  "ω_af / ω_ab (V/µm): its weight on the trace (rising voltage) / retrace (falling voltage) branch; "
                  "e_ω = |ω_af − ω_ab| / |ω_ab| (paper eq. 7): how far the two branch weights differ, relative to "
                  "the retrace weight — large where ω_ab is near zero (a ratio to a near-zero slope, not an error).")


def identification_table1_markdown(result) -> str:
    """Table 1 analogue as Markdown: DIAPI widths, slopes and e_ω with the column definitions."""
    m = result.models["diapi"]
    rows = [[str(i), f"{r * 1e6:.1f}", f"{wf * 1e-6:.4f}", f"{wb * 1e-6:.4f}", _pct(abs(e))]
            for i, (r, wf, wb, e) in enumerate(zip(m.widths, m.weights_trace, m.weights_retrace, m.asymmetry), 1)]
    return "\n".join(["**Table 1 analogue: identified DIAPI parameters**", "", TABLE1_COLUMNS, "",
                      markdown_table(["i", "r (µm)", "ω_af (V/µm)", "ω_ab (V/µm)", "e_ω (eq. 7)"], rows)]) + "\n"


def identification_table1_csv(result) -> str:
    """Table 1 analogue CSV: DIAPI widths r (µm), slopes ω_af, ω_ab (V/µm), e_ω (eq. 7)."""
    m = result.models["diapi"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["i", "r_um", "omega_af_V_per_um", "omega_ab_V_per_um", "e_omega"])
    for i, (r, wf, wb, e) in enumerate(zip(m.widths, m.weights_trace, m.weights_retrace, m.asymmetry), 1):
        w.writerow([i, f"{r * 1e6:.6g}", f"{wf * 1e-6:.6g}", f"{wb * 1e-6:.6g}", f"{abs(e):.6g}"])
    return buf.getvalue()
