"""Figures and tables of ``afmsim identify`` (paper Figs. 6–7, Tables 1–2 analogues)."""

from __future__ import annotations

from pathlib import Path

from .paper_figures import plot_identification_errors, plot_identification_loops
from .tables import identification_table1_csv, identification_table1_markdown, identification_table2

__all__ = ["write_identification_report"]


def write_identification_report(result, folder) -> list[Path]:
    """Write ``fig6_loops.png``, ``fig7_errors.png``, ``table2.md``, ``table2.csv`` and (when DIAPI
    was identified) ``table1.csv`` and ``table1.md`` (with the column definitions, e_ω = eq. 7) into
    ``folder``; returns the paths."""
    folder = Path(folder)
    written = [plot_identification_loops(result, folder / "fig6_loops.png"),
               plot_identification_errors(result, folder / "fig7_errors.png")]
    md, csv_text = identification_table2(result)
    (folder / "table2.md").write_text(md)
    (folder / "table2.csv").write_text(csv_text)
    written += [folder / "table2.md", folder / "table2.csv"]
    if "diapi" in result.models:
        (folder / "table1.csv").write_text(identification_table1_csv(result))
        (folder / "table1.md").write_text(identification_table1_markdown(result))
        written += [folder / "table1.csv", folder / "table1.md"]
    return written
