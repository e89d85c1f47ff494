"""What a scenario already models: the stage switches that make an effect part of the baseline.

Shared by the loop and the image diagnosis. An effect the scenario switches on is fitted with the
baseline and is not a candidate (the question is what the *model* lacks).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["modelled_effects", "as_scenario"]


def as_scenario(scenario):
    """A :class:`~afmsim.scenario.Scenario` from a Scenario, a YAML path or None (raises ScenarioError)."""
    if scenario is None or not isinstance(scenario, (str, Path)):
        return scenario
    from afmsim.scenario import load_scenario

    return load_scenario(scenario)


def modelled_effects(scenario) -> tuple[str, ...]:
    """Candidate effects switched on in ``scenario.stage``: creep, drift, dynamics (resonance),
    cross_coupling (coefficient > 0); () without a scenario."""
    if scenario is None:
        return ()
    s = scenario.stage
    on = {"creep": s.creep, "drift": s.drift, "dynamics": s.dynamics, "cross_coupling": s.cross_coupling > 0}
    return tuple(k for k, v in on.items() if v)
