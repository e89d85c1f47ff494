"""Regenerate the README gallery from the bundled scenarios (the same figures ``afmsim run`` writes).

    python docs/gallery/regenerate.py

* ``quick_figure_none.png``, ``quick_binarized.png``, ``quick_render_trace.png``:
  ``scenarios/quick.yaml`` (experiment 1, all four controllers, so the colour scale is the run's);
* ``grating_none.png``, ``grating_iiapi.png``: ``scenarios/grating.yaml``, experiment 1 with
  the controllers none and IIAPI only (the same experiment-1 scans as the full run; the colour
  scale is that of these two).

PNGs are shrunk to the README's width with Pillow.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from PIL import Image

from afmsim.experiment import run_scenario
from afmsim.report.run_output import write_run
from afmsim.scenario import load_scenario

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


def _shrink(source: Path, target: Path, width: int) -> None:
    with Image.open(source) as im:
        height = round(im.height * width / im.width)
        im.convert("RGB").resize((width, height), Image.LANCZOS).save(target, optimize=True)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        quick = Path(tmp) / "quick"
        quick.mkdir()
        scenario = load_scenario(ROOT / "scenarios" / "quick.yaml").model_copy(update={"experiments": 1})
        write_run(run_scenario(scenario, workers=2), quick, renders="key", workers=2)
        _shrink(quick / "figure_none.png", HERE / "quick_figure_none.png", 1100)
        _shrink(quick / "binarized.png", HERE / "quick_binarized.png", 1100)
        _shrink(quick / "render_none_trace.png", HERE / "quick_render_trace.png", 560)
        grating = Path(tmp) / "grating"
        grating.mkdir()
        scenario = load_scenario(ROOT / "scenarios" / "grating.yaml").model_copy(
            update={"experiments": 1, "controllers": ["none", "iiapi"]})
        write_run(run_scenario(scenario, workers=2), grating, renders="none", workers=2)
        for name in ("none", "iiapi"):
            _shrink(grating / f"figure_{name}.png", HERE / f"grating_{name}.png", 1100)


if __name__ == "__main__":
    main()
