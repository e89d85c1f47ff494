"""The loop diagnosis' creep candidate (afmsim.diagnosis.loops.model): a bank of relaxations slow
enough for a creep that is still rising when the record ends."""

import numpy as np
import pytest

from afmsim.diagnosis.loops import model
from afmsim.diagnosis.loops.model import CREEP_SPAN_FACTOR, Design, ModelSpec, creep_taus, fit_model
from afmsim.diagnosis.loops.open_world import creep_term
from afmsim.diagnosis.loops.validation import excitation
from afmsim.stage import AsymmetricPreisach


def _stage_record(seed: int):
    """afmsim's own stage under triangles for 24 s at 250 Hz, 3 nm sensor noise; the first 60 % is
    the training part."""
    rng = np.random.default_rng(seed)
    t, v = excitation("triangles", 250.0, 24.0, rng)
    x = AsymmetricPreisach().apply(v) + 3e-9 * rng.standard_normal(t.size)
    return t, v, x, np.arange(t.size) < int(0.6 * t.size)


def _heldout_gap(d: Design, effects: tuple) -> float:
    held, _ = d.scored()
    fitted = fit_model(d, ModelSpec(kind=d.family, effects=effects))
    return float(np.sqrt(np.mean((d.x - fitted.prediction)[held] ** 2)))


def test_the_creep_bank_reaches_beyond_the_training_span():
    taus = creep_taus(0.004, 14.4)
    assert taus[-1] == pytest.approx(CREEP_SPAN_FACTOR * 14.4)
    assert taus[0] == pytest.approx(0.02)
    assert np.all(np.diff(np.log10(taus)) < 2.0)  # about one per decade


def test_a_creep_still_rising_at_the_records_end_is_followed_by_the_slower_bank(monkeypatch):
    """A stretched-exponential creep (τ 15 s, β 0.45, 2 %/decade) on a 24 s record: a bank that stops
    at the 14 s training span settles while the stage still creeps; the bank to 10 spans leaves a
    held-out gap at least a third smaller."""
    t, v, x, train = _stage_record(4)
    h = AsymmetricPreisach().apply(v)

    class FixedShape:  # creep_term draws (τ, β) from its generator: pin them
        def uniform(self, lo, hi):
            return {(1.0, 20.0): 15.0, (0.3, 0.6): 0.45}[(lo, hi)]

    record = x + creep_term(t, h, 0.02, "stretched", FixedShape())
    gaps = {}
    for factor in (1.0, CREEP_SPAN_FACTOR):
        monkeypatch.setattr(model, "CREEP_SPAN_FACTOR", factor)
        d = Design(t, v, record, None, train)
        gaps[factor] = _heldout_gap(d, ("creep",))
    assert gaps[CREEP_SPAN_FACTOR] < (2 / 3) * gaps[1.0], gaps
