"""Regenerate ``shift_baseline.json`` — run only when a physics change is intended, and say so in the commit.

    python tests/regression/regenerate.py
"""

import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from afmsim.experiment import run_scenario  # noqa: E402
from afmsim.scenario import load_scenario  # noqa: E402

TOLERANCES = {"shift_x_m_abs": 5e-9, "nsl2_rel": 0.02}


def main() -> None:
    metrics = run_scenario(load_scenario(HERE / "shift_scenario.yaml")).metrics()
    baseline = {"scenario": "shift_scenario.yaml", "tolerances": TOLERANCES,
                "controllers": {name: {"shift_x_m": c["shift_x_m"]["mean"], "nsl2": c["nsl2"]["mean"]}
                                for name, c in metrics["controllers"].items()}}
    (HERE / "shift_baseline.json").write_text(json.dumps(baseline, indent=2) + "\n")
    print(json.dumps(baseline, indent=2))


if __name__ == "__main__":
    main()
