"""The run report: ``report.html`` (self-contained, PNGs embedded as base64) and ``report.md``
(links to the PNG files), built from one list of blocks so both say the same.

First screen: what was run, the headline table, and a plain-language reading of it (which
controller won, by how much, why at this scan size, how the paper's values compare and what makes
them (in)comparable). Then the definitions of the scores, provenance, the key figures with
captions; per-controller figures, binarized images, 3D renders, the per-experiment NSL2 table and
the scenario YAML follow folded (``<details>``).
"""

from __future__ import annotations

import base64
import html
import math
import re
from pathlib import Path

from .tables import PAPER_COLUMNS, markdown_table, paper_nsl2_for

__all__ = ["write_report", "best_controller", "reading", "DEFINITIONS", "metrics_markdown"]

UM = 1e-6
#: Pixels of the paper's images (256 × 256): NSL2 grows with the pixel count.
PAPER_PIXELS = 256 * 256
#: Travel of afmsim's default stage (m): 100 µm at 9.1 V.
STAGE_TRAVEL_M = 100e-6

_CONTROLLER_WHAT = {
    "none": "no compensation (nominal sensitivity)",
    "spi": "symmetric PI inverse (SPI)",
    "diapi": "direct inverse asymmetric PI (DIAPI, the paper's model)",
    "iiapi": "indirect inverse asymmetric PI (IIAPI)",
    "capi": "continuous asymmetric PI (CAPI)",
    "vendor": "vendor polynomial per direction (the paper's Bruker column)",
    "ideal": "stage without hysteresis and creep (the floor)",
}

#: Definitions of every score in the report (Markdown, one item each).
DEFINITIONS = (
    "**NSL2** (paper eq. 8): trace and retrace are each binarized at their own mean height; "
    "NSL2 = 2n(1 − r), r the correlation of the two binary images over their n pixels, i.e. about twice the "
    "number of pixels where they disagree. 0 = identical. It grows with the pixel count: compare runs and the "
    "paper by ratios (e.g. D/D_A) unless the images have the same size.",
    "**e_D** (eq. 9) = (D_S − D_A)/D_S: how much lower DIAPI's NSL2 (D_A) is than SPI's (D_S). Positive: DIAPI "
    "better; negative: DIAPI worse (−100 % = twice SPI's NSL2).",
    "**shift x** (µm): the sub-pixel translation of the retrace relative to the trace, retrace(x) ≈ trace(x − "
    "shift); negative = the retrace's features sit to the left (−x) of the trace's (the uncompensated "
    "hysteresis lag). **lens centre shift x**: the same for the lens nearest the image centre (immune to the "
    "lattice aliasing of the whole-image shift).",
    "**scale x** = intended x span of the pixels / x span the tip really travelled (median over lines, both "
    "directions): 1 = true scale, 1.26 = every feature drawn 26 % too wide (the stage fell short).",
    "**× ideal** = NSL2 / NSL2 of the ideal controller (the same stage without hysteresis and creep): what "
    "compensation could still gain; 1 is the floor.",
    "Heights in every image are **above the substrate**: each image's substrate level is the commonest level among its "
    "pixels below its mean height (the background NSL2's binarization sees).",
)


def _num(v, spec):
    return "–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def _mean(metrics: dict, controller: str, metric: str):
    return metrics["controllers"].get(controller, {}).get(metric, {}).get("mean")


def best_controller(metrics: dict) -> str | None:
    """The compensating controller with the lowest mean NSL2 (``none`` and ``ideal`` excluded;
    ``ideal`` when it is the only one), or None."""
    nsl2 = {c: s["nsl2"]["mean"] for c, s in metrics["controllers"].items()
            if s["nsl2"]["mean"] is not None and math.isfinite(s["nsl2"]["mean"])}
    pool = {c: v for c, v in nsl2.items() if c not in ("none", "ideal")} or \
        {c: v for c, v in nsl2.items() if c != "none"}
    return min(pool, key=pool.get) if pool else None


def metrics_markdown(metrics: dict, kind: str = "microlens") -> str:
    """The headline table: controller, what it is, NSL2 mean ± σ, × ideal, shifts, scale, paper's NSL2."""
    _, paper = paper_nsl2_for(kind)
    over = metrics.get("nsl2_over_ideal", {})
    rows = []
    for name, s in metrics["controllers"].items():
        centre = _mean(metrics, name, "lens_centre_shift_x_m")
        column = PAPER_COLUMNS.get(name)
        rows.append([f"**{name}**", _CONTROLLER_WHAT.get(name, name),
                     f"{_num(s['nsl2']['mean'], ',.0f')} ± {_num(s['nsl2']['std'], ',.0f')}",
                     _num(over.get(name), ".2f"), _num(s["shift_x_m"]["mean"] / UM, "+.3f"),
                     _num(centre / UM if centre is not None else None, "+.3f"),
                     _num(_mean(metrics, name, "scale_x"), ".3f"),
                     f"{paper[column]:,.0f} ({column})" if column else "–"])
    return markdown_table(["controller", "what it is", "NSL2 mean ± σ", "× ideal", "shift x (µm)",
                           "lens centre shift x (µm)", "scale x", "paper NSL2"], rows)


def _scan_words(scenario) -> str:
    s = scenario.scan
    return (f"{s.size_um[0]:g} × {s.size_um[1]:g} µm from ({s.offset_um[0]:g}, {s.offset_um[1]:g}) µm, "
            f"{s.pixels} × {s.lines} px, {s.line_rate_hz:g} Hz line rate (trace left → right)")


def _sample_words(sample) -> str:
    if sample.kind == "microlens":
        return (f"micro-lens array ({sample.diameter_um:g} µm lenses, {sample.sag_um:g} µm high, {sample.pitch_um:g} µm "
                f"pitch, {sample.arrangement})")
    if sample.kind == "grating":
        return f"grating ({sample.period_um:g} µm period, {sample.step_nm:g} nm step, duty cycle {sample.duty_cycle:g})"
    return f"{sample.kind} from {sample.path}"


def what_was_run(scenario) -> str:
    """One paragraph: sample, scan, controllers, experiments, identification."""
    ident = scenario.identification
    loop = ("reduced to the scan's own range" if ident.range == "scan"
            else f"{ident.amplitude_V:g} V (≈ {ident.amplitude_V / 9.1 * 100:.0f} µm)")
    return (f"**What was run.** Sample: {_sample_words(scenario.sample)}. Scan: {_scan_words(scenario)}. "
            f"Controllers: {', '.join(dict.fromkeys(scenario.controllers))}. {scenario.experiments} experiment(s) "
            f"(seed {scenario.seed}), each with its own identification loop ({loop}) and sensor/Z-loop noise.")


def reading(metrics: dict, scenario) -> list[str]:
    """The plain-language reading of a run's scores (Markdown paragraphs)."""
    nsl2 = {c: _mean(metrics, c, "nsl2") for c in metrics["controllers"]}
    kind = scenario.sample.kind
    label, paper = paper_nsl2_for(kind)
    out = []
    best = best_controller(metrics)
    if best is not None:
        parts = [f"**Best compensation: {best}**, NSL2 {nsl2[best]:,.0f}"]
        if nsl2.get("none") and nsl2[best] > 0:
            parts.append(f"{nsl2['none'] / nsl2[best]:.1f}× lower than without compensation ({nsl2['none']:,.0f})")
        if nsl2.get("ideal"):
            parts.append(f"{nsl2[best] / nsl2['ideal']:.1f}× the hysteresis-free floor (ideal, {nsl2['ideal']:,.0f})")
        out.append(", ".join(parts) + ".")
    if isinstance(metrics.get("e_D"), (int, float)) and math.isfinite(metrics["e_D"]):
        e = metrics["e_D"]
        verdict = (f"DIAPI beats SPI: e_D = {e:+.0%}" if e > 0 else
                   f"**DIAPI is worse than SPI here**: e_D = {e:+.0%} (DIAPI's NSL2 {nsl2['diapi']:,.0f} vs SPI's "
                   f"{nsl2['spi']:,.0f})")
        out.append(f"{verdict}; the paper found e_D = {paper['e_D']:+.1%} ({label}).")
        span = scenario.scan.size_um[0] * UM
        law = getattr(scenario.stage, "hysteresis", "preisach")
        if e <= 0:
            plant = ("afmsim's default (Preisach) stage shapes its minor-loop branches by the reversal points, not by the "
                     "direction, and on it DIAPI overtakes SPI only on scans from about 70 µm "
                     "(`scenarios/microlens_full_range.yaml`: e_D ≈ +59 %)" if law == "preisach" else
                     f"how far that matters depends on the plant's minor-loop law (here {law})")
            out.append(
                f"**Why, at this scan size.** The scan spans {span / UM:g} µm of the stage's {STAGE_TRAVEL_M / UM:.0f} µm "
                "travel, so the stage runs on minor loops. DIAPI switches between separate trace and retrace weights "
                "(ω_af, ω_ab, eqs. 5–7) with the direction of motion, so its drive jumps by Σ(ω_af − ω_ab)·H at every "
                f"reversal; the least-squares fit makes that jump vanish only at the ends of the identification loop; "
                f"{plant} (docs/reference-results.md). The paper does not state its scan size.")
        else:
            out.append(f"The scan spans {span / UM:g} µm of the stage's {STAGE_TRAVEL_M / UM:.0f} µm travel: DIAPI's "
                       "direction-switched weights transfer from the identification loop, as in the paper.")
    if nsl2.get("vendor") and nsl2.get("none") and nsl2["vendor"] > nsl2["none"]:
        out.append(f"The vendor polynomial ({nsl2['vendor']:,.0f}) is worse than no compensation: it has no memory of "
                   "where the last reversal was, so it is exact only on the loop it was fitted to and over-corrects "
                   "the scan's smaller loops.")
    scale_none, scale_best = _mean(metrics, "none", "scale_x"), _mean(metrics, best, "scale_x") if best else None
    if scale_none is not None:
        text = f"Without compensation the image is drawn at ×{scale_none:.2f} scale along x"
        if scale_best is not None:
            text += f" ({best}: ×{scale_best:.2f})"
        out.append(text + " (scale x, defined below).")
    pixels = scenario.scan.pixels * scenario.scan.lines
    if pixels != PAPER_PIXELS:
        out.append(f"**Comparing with the paper.** NSL2 grows with the pixel count: this run has {scenario.scan.pixels} × "
                   f"{scenario.scan.lines} = {pixels:,} pixels, the paper 256 × 256 = {PAPER_PIXELS:,}, so compare ratios "
                   "(D/D_A, e_D), not absolute NSL2. The paper's stage and sample are not afmsim's, and its scan size is "
                   "not stated; afmsim's stage is calibrated to the paper's identification loop (Tables 1–2), not to "
                   "Tables 3–4.")
    else:
        out.append("**Comparing with the paper.** Same image size as the paper (256 × 256), so NSL2 values are on the "
                   "same footing; the stage and sample are afmsim's (calibrated to the paper's identification loop, "
                   "Tables 1–2, not to Tables 3–4), and the paper does not state its scan size.")
    saturation = _saturation_words(metrics)
    if saturation:
        out.append(saturation)
    return out


def _saturation_words(metrics: dict) -> str | None:
    """A warning when any drive saturated during the run (``saturated_fraction`` scores or a
    ``saturation`` block in ``metrics.json``), else None."""
    hit = {c: _mean(metrics, c, "saturated_fraction") for c in metrics["controllers"]}
    hit = {c: v for c, v in hit.items() if v}
    if hit:
        return ("**Saturation:** a drive sat at its limit during " +
                ", ".join(f"{v:.2%} of {c}'s scan" for c, v in hit.items()) +
                " — those parts of the images are flat where the stage could not follow.")
    block = metrics.get("saturation")
    if block and any(bool(v) for v in (block.values() if isinstance(block, dict) else [block])):
        return f"**Saturation:** {block}"
    return None


# --------------------------------------------------------------------------- blocks → Markdown / HTML


def _inline(text: str) -> str:
    text = html.escape(text)
    text = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", text)
    return re.sub(r"`(.+?)`", r"<code>\1</code>", text)


def _md_table_to_html(md: str) -> str:
    """The Markdown of :mod:`afmsim.report.tables` (tables, bold lines, text) as HTML."""
    out, table = [], []

    def flush():
        if not table:
            return
        head, *body = [[c.strip() for c in line.strip().strip("|").split("|")] for line in table
                       if not re.fullmatch(r"\|[:\-|]+\|", line.strip())]
        cells = lambda row, tag: "".join(f"<{tag}>{_inline(c)}</{tag}>" for c in row)  # noqa: E731
        out.append("<table><thead><tr>" + cells(head, "th") + "</tr></thead><tbody>"
                   + "".join("<tr>" + cells(r, "td") + "</tr>" for r in body) + "</tbody></table>")
        table.clear()

    for line in md.splitlines():
        if line.strip().startswith("|"):
            table.append(line)
            continue
        flush()
        if line.strip():
            out.append(f"<p>{_inline(line)}</p>")
    flush()
    return "\n".join(out)


def _to_md(blocks) -> list[str]:
    md = []
    for block in blocks:
        kind = block[0]
        if kind == "h2":
            md += [f"## {block[1]}", ""]
        elif kind in ("p", "table"):
            md += [block[1], ""]
        elif kind == "list":
            md += [f"- {item}" for item in block[1]] + [""]
        elif kind == "pre":
            md += ["```yaml", block[1].rstrip(), "```", ""]
        elif kind == "figure":
            md += [f"![{block[1].stem}]({block[1].name})", "", f"*{block[2]}*", ""]
        elif kind == "details":
            md += ["<details>", f"<summary>{block[1]}</summary>", ""] + _to_md(block[2]) + ["</details>", ""]
    return md


def _to_html(blocks) -> list[str]:
    body = []
    for block in blocks:
        kind = block[0]
        if kind == "h2":
            body.append(f"<h2>{html.escape(block[1])}</h2>")
        elif kind == "p":
            body.append(f'<p class="{block[2]}">' if len(block) > 2 else "<p>")
            body[-1] += _inline(block[1]) + "</p>"
        elif kind == "table":
            body.append(_md_table_to_html(block[1]))
        elif kind == "list":
            body.append("<ul>" + "".join(f"<li>{_inline(item)}</li>" for item in block[1]) + "</ul>")
        elif kind == "pre":
            body.append(f"<pre>{html.escape(block[1])}</pre>")
        elif kind == "figure":
            data = base64.b64encode(block[1].read_bytes()).decode("ascii")
            body.append(f'<figure><img alt="{html.escape(block[1].stem)}" src="data:image/png;base64,{data}">'
                        f"<figcaption><b>{html.escape(block[1].name)}</b> — {_inline(block[2])}</figcaption></figure>")
        elif kind == "details":
            body += [f"<details><summary>{html.escape(block[1])}</summary>"] + _to_html(block[2]) + ["</details>"]
    return body


_CSS = """body{font-family:sans-serif;max-width:1250px;margin:auto;padding:1em;color:#222;line-height:1.4}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}
td:first-child,th:first-child,td:nth-child(2){text-align:left}th{background:#eee}pre{background:#f6f6f6;padding:.6em;
overflow:auto;font-size:12px}img{max-width:100%;border:1px solid #ddd;margin:.3em 0}figure{margin:.8em 0}
figcaption{font-size:90%;color:#444}details{margin:.5em 0;padding:.3em .6em;border:1px solid #ddd;border-radius:4px}
summary{cursor:pointer;font-weight:bold}.warn{color:#a40;font-weight:bold}.reading{background:#f4f8ff;padding:.5em}"""

_RUN_SCALE = ("heights above the substrate on the run's colour scale (0.1st–99.9th percentile of every image of "
              "the run; blue = below, cyan = above the range)")


def _figure_caption(name: str, kind: str) -> str:
    line = ("the averaged profile across the lines" if kind == "grating" else
            "the scan line through the central lens (white cross in (a); its trace position dashed in (b))")
    return (f"Controller {name}, experiment 1 (paper Fig. 10–13 analogue): (a) trace (left → right) and (b) retrace "
            f"(right → left), {_RUN_SCALE}; (c) trace − retrace in nm on one symmetric scale for all controllers "
            "(red: the trace is higher) — a perfect stage leaves only noise there, hysteresis a red/blue pair on each "
            f"feature edge; (d) {line}, trace solid, retrace dashed; (e) the grey box of (d), magnified where trace "
            "and retrace differ most.")


def write_report(folder, *, result, metrics: dict, nsl2_md: str, scenario_yaml: str, figures: list, renders: list,
                 renders_choice: str, best: str | None, warnings: list[str], provenance: dict) -> list[Path]:
    """Write ``report.html`` and ``report.md`` into ``folder`` (figures embedded in the HTML as
    ``data:image/png;base64`` URIs, linked by relative path in the Markdown)."""
    folder = Path(folder)
    scenario, kind = result.scenario, result.scenario.sample.kind
    pngs = {Path(p).name: Path(p) for p in [*figures, *renders] if Path(p).is_file()}
    key = list(dict.fromkeys(c for c in ("none", best) if c in metrics["controllers"]))
    others = [c for c in metrics["controllers"] if c not in key]

    def fig(name, caption):
        return [("figure", pngs[name], caption)] if name in pngs else []

    blocks = [("p", f"**warning:** {w}", "warn") for w in warnings]
    blocks += [("p", what_was_run(scenario)), ("table", metrics_markdown(metrics, kind))]
    blocks += [("p", text, "reading") for text in reading(metrics, scenario)]
    for note in metrics.get("notes", []):
        blocks.append(("p", f"note: {note}"))
    blocks += [("h2", "Definitions"), ("list", list(DEFINITIONS))]
    commit = provenance.get("commit") or "unknown"
    dirty = " (with uncommitted changes)" if provenance.get("dirty") else ""
    timing = ", ".join(f"{label} {provenance[k]:.1f} s" for k, label in (
        ("simulate_s", "identification + scans"), ("metrics_s", "scores"), ("figures_s", "files, figures and renders"))
        if isinstance(provenance.get(k), (int, float)))
    blocks += [("h2", "Provenance"), ("p", f"afmsim {provenance.get('afmsim')}, commit {commit[:12]}{dirty}, written "
                                          f"{provenance.get('date_utc')}; seed {scenario.seed}; {timing} on "
                                          f"{provenance.get('workers', 1)} worker process(es). Full record: "
                                          "`manifest.json` (package versions, timings, command line).")]
    blocks += [("h2", "Trace vs retrace: the uncompensated and the best controller")]
    for name in key:
        blocks += fig(f"figure_{name}.png", _figure_caption(name, kind))
    folded = []
    if others:
        folded.append(("details", f"Every other controller ({', '.join(others)}): trace, retrace, difference, "
                                  "cross-section",
                       [b for n in others for b in fig(f"figure_{n}.png", _figure_caption(n, kind))]))
    folded.append(("details", "Binarized images (what NSL2 compares)",
                   fig("binarized.png", "Trace and retrace of every controller, each binarized at its own mean height "
                                        "(eq. 8) and overlaid: white/black where they agree, red where only the trace "
                                        "is above its mean, blue where only the retrace is — NSL2 counts these "
                                        "pixels (≈ 2 × their number).")))
    render_blocks = [b for p in renders if Path(p).name in pngs for b in fig(
        Path(p).name, "3D view, heights above the substrate; one colour range and one vertical exaggeration for the "
                      "sample and every scan of the run (written in the view).")]
    if render_blocks:
        folded.append(("details", f"3D renders ({renders_choice}: "
                                  f"{'the sample, the uncompensated and the best controller' if renders_choice == 'key' else 'every controller'})",
                       render_blocks))
    folded.append(("details", "NSL2 per experiment (paper Table 3/4 analogue)", [("table", nsl2_md.rstrip())]))
    folded.append(("details", "Scenario (YAML)", [("pre", scenario_yaml)]))
    blocks += [("h2", "More")] + folded

    title = f"afmsim run report: {scenario.name}"
    md = [f"# {title}", ""] + _to_md(blocks)
    page = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>\n"
            f"<h1>{html.escape(title)}</h1>\n" + "\n".join(_to_html(blocks)) + "\n</body></html>\n")
    (folder / "report.html").write_text(page, encoding="utf-8")
    (folder / "report.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    return [folder / "report.html", folder / "report.md"]
