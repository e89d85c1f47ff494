"""Report outputs: files other tools read (Gwyddion ``.gwy``)."""

from afmsim.report.gwy import read_gwy, write_gwy

__all__ = ["write_gwy", "read_gwy"]
