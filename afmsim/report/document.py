"""The run report: ``report.html`` (self-contained, PNGs embedded as base64) and ``report.md``
(links to the PNG files), with the same sections and tables:

scenario YAML · metrics table · NSL2 table (Table 3/4 analogue, paper beside afmsim) · height
images · paper-figure analogues · binarized images · 3D renders (or the reason they are missing).
"""

from __future__ import annotations

import base64
import html
import math
import re
from pathlib import Path

__all__ = ["write_report"]


def _num(v, spec):
    return "–" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def metrics_markdown(metrics: dict) -> str:
    """Controllers × (NSL2 mean, σ, shift x, lens-centre shift, NSL2 / ideal) as Markdown."""
    from .tables import markdown_table

    over = metrics.get("nsl2_over_ideal", {})
    rows = []
    for name, s in metrics["controllers"].items():
        centre = s.get("lens_centre_shift_x_m", {}).get("mean")
        rows.append([name, _num(s["nsl2"]["mean"], ",.1f"), _num(s["nsl2"]["std"], ",.1f"),
                     _num(s["shift_x_m"]["mean"] * 1e6, ".3f"),
                     _num(centre * 1e6 if centre is not None else None, ".3f"),
                     _num(over.get(name), ".2f")])
    out = markdown_table(["controller", "NSL2 mean", "NSL2 σ", "shift x (µm)", "lens centre shift x (µm)",
                          "NSL2 / ideal"], rows)
    if "e_D" in metrics:
        out += f"\n\ne_D (SPI → DIAPI, eq. 9): {metrics['e_D']:.1%}"
    return out


def _md_table_to_html(md: str) -> str:
    """Convert the Markdown produced by :mod:`afmsim.report.tables` (tables, bold lines, text) to HTML."""
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


def _inline(text: str) -> str:
    return re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", html.escape(text))


_CSS = """body{font-family:sans-serif;max-width:1250px;margin:auto;padding:1em;color:#222}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}
td:first-child,th:first-child{text-align:left}th{background:#eee}pre{background:#f6f6f6;padding:.6em;
overflow:auto;font-size:12px}img{max-width:100%;border:1px solid #ddd;margin:.3em 0}
.grid{display:grid;grid-template-columns:1fr 1fr;gap:8px}.warn{color:#a40;font-weight:bold}"""


def write_report(folder, *, name: str, scenario_yaml: str, metrics: dict, nsl2_md: str,
                 sections: list[tuple[str, list[Path]]], warnings: list[str]) -> list[Path]:
    """Write ``report.html`` and ``report.md`` into ``folder``.

    ``sections`` are (heading, PNG paths) in display order; images are embedded in the HTML as
    ``data:image/png;base64`` URIs and linked by relative path in the Markdown.
    """
    folder = Path(folder)
    metrics_md = metrics_markdown(metrics)
    md = [f"# afmsim run report: {name}", ""]
    md += [f"> **warning:** {w}" for w in warnings] + ([""] if warnings else [])
    md += ["## Scenario", "", "```yaml", scenario_yaml.rstrip(), "```", "",
           "## Metrics", "", metrics_md, "", "## NSL2 table (paper analogue)", "", nsl2_md.rstrip(), ""]
    body = [f"<h1>afmsim run report: {html.escape(name)}</h1>"]
    body += [f'<p class="warn">warning: {html.escape(w)}</p>' for w in warnings]
    body += ["<h2>Scenario</h2>", f"<pre>{html.escape(scenario_yaml)}</pre>",
             "<h2>Metrics</h2>", _md_table_to_html(metrics_md),
             "<h2>NSL2 table (paper analogue)</h2>", _md_table_to_html(nsl2_md)]
    for heading, paths in sections:
        paths = [Path(p) for p in paths if Path(p).is_file()]
        if not paths:
            continue
        md += [f"## {heading}", ""] + [f"![{p.stem}]({p.name})" for p in paths] + [""]
        grid = "grid" if heading.lower().startswith("3d") else ""
        body += [f"<h2>{html.escape(heading)}</h2>", f'<div class="{grid}">']
        for p in paths:
            data = base64.b64encode(p.read_bytes()).decode("ascii")
            body.append(f'<figure><img alt="{html.escape(p.stem)}" src="data:image/png;base64,{data}">'
                        f"<figcaption>{html.escape(p.name)}</figcaption></figure>")
        body.append("</div>")
    page = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\">"
            f"<title>afmsim report: {html.escape(name)}</title><style>{_CSS}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")
    (folder / "report.html").write_text(page, encoding="utf-8")
    (folder / "report.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    return [folder / "report.html", folder / "report.md"]
