"""Fig. 8 analogue: DIAPI vs IIAPI identification time saving over M and N.

Reads ``benchmarks/results/identification_timing.json`` (written by ``bench_identification.py``)
and writes ``benchmarks/results/fig8_time_saving.png``::

    PYTHONPATH=. python benchmarks/plot_fig8.py [timing.json] [out.png]

Python: ``afmsim.report.paper_figures.plot_time_saving(json_path, png_path)``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from afmsim.report.paper_figures import plot_time_saving

RESULTS = Path(__file__).resolve().parent / "results"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    source = Path(argv[0]) if argv else RESULTS / "identification_timing.json"
    target = Path(argv[1]) if len(argv) > 1 else RESULTS / "fig8_time_saving.png"
    print(f"wrote {plot_time_saving(source, target)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
