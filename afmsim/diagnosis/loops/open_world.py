"""Open-world validation of the loop diagnosis (issue 11, point 5).

Unlike the closed-world suite (:mod:`.validation`: afmsim's own plant, effects at 10–100× the
datasheet), every case here is a record from

* a **plant** drawn from afmsim's own stage (:class:`afmsim.stage.AsymmetricPreisach`) *and* the
  other hysteresis families of :mod:`.null_plants` (scattered-relay Preisach, generalised
  Prandtl–Ishlinskii, Bouc–Wen) — none of them the baseline's relay grid;
* one of three **case types**:

  - *effect* cases: one (or two) candidate effects injected through forms unlike the candidates'
    equations (below), at datasheet magnitudes (``../shared/reference/physics-datasheet.md``:
    drift 1–50 nm/min, creep 1–2 %/decade, X–Y coupling 0.1–1 %, first resonance 300 Hz–3 kHz)
    and at one large magnitude that stays inside the documented plausible range
    (:mod:`afmsim.diagnosis.plausible`);
  - *null* cases: no effect, two per plant family;
  - *distractor* cases: an effect that is no candidate (:mod:`.distractors`: mains pickup, a
    mechanical slip, a sensor gain that changes during the record, loop width that grows with the
    drive rate), at a small and a large magnitude;

* one of three **timings**: ``standard`` (500 Hz–2 kHz, 8–16 s), ``long`` (200 Hz–1 kHz, 30–60 s,
  decimated by the loader to ≤ 8000 samples) and ``fast`` (8000 samples at 3–20 kHz: the voltage
  path of a 1 kHz, 8 s excitation played 3–20× faster, so a 300 Hz–3 kHz resonance is sampled
  ≥ 6.7× and excited by the drive's corners). The drives are the excitations of :mod:`.validation`
  (triangle trains, steps with holds, sine trains, band-limited noise), redrawn until the held-out
  last 40 % stays inside the training part's voltage range (the protocol's condition: no
  rate-independent model can know relays that only the held-out part switches).

Injected forms (the candidates in :mod:`.model` are: drift quadratic in t; creep a bank of
first-order relaxations; dynamics a first-order lag after the hysteresis, with a first-order-hold
second-order mode after it where the training part rings; coupling ``c·y_m``):

* creep — superposition of step responses of every increment of the hysteresis output, with a
  log-law kernel ``a·log10(1 + t/τ0)`` or a stretched exponential ``a·(1 − exp(−(t/τ)^β))``
  (β 0.3–0.6); the magnitude γ is the kernel's rise per decade between 0.1 s and 10 s (the
  datasheet's ``d(t) = d(0.1 s)·[1 + γ·log10(t/0.1 s)]``);
* drift — exponential warm-up ``1 − exp(−t/τw)`` (τw 0.3–2 × the record) or a smooth random walk
  (integrated low-passed noise); the magnitude (m/s) is the warm-up's least-squares rate over the
  record, and the walk's peak-to-peak excursion over the record divided by its span (a walk that
  wanders back has almost no least-squares slope: scaled to one, it wandered by up to 400× its
  label — :func:`drift_term`);
* dynamics — a high-voltage amplifier pole acting on the *voltage* before the hysteresis
  (first-order-hold discretisation), and a lightly damped resonance (ζ 0.01–0.05) acting on the
  displacement after it (bilinear transform pre-warped at f0); the magnitude is the resonance frequency f0 (datasheet cases: amplifier
  pole at 3–10 × f0; large case: f0 300 Hz with a 60 Hz amplifier pole);
* cross-coupling — ``c·(y + q·(y − ȳ)²/range(y))`` with the cross axis' *true* motion y from its
  own hysteretic plant (same family, other parameters) and a flexure's quadratic arc
  (q −0.3…0.3); the diagnosis sees the noisy ``y_m``.

Scores (:func:`score_cases`), each proportion with its Wilson 95 % interval: effect-case top-1
(first verdict entry is a true effect) and exact-set accuracy over *all* effect cases and over the
*visible* ones (the injected effect raises the baseline's held-out mean square by at least the
noise variance σ², by an oracle: the same baseline fitted on the same record without the effect),
the false-attribution rate (a named effect, i.e. a non-empty verdict, implausible ones included),
the false-findings rate (a plausible named effect) and the ``explained`` rate on null and on
distractor cases, the null gap-to-noise per plant family, the status counts per case
type and the detection-versus-magnitude table (detected = the effect is in the verdict).

Seeds: **1–6 were the development seeds**; the figures in docs/diagnosis.md come from fresh seeds
(``benchmarks/bench_open_world.py``; :data:`FRESH_SEEDS`), run once after the method was frozen.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.signal import bilinear, butter, cont2discrete, lfilter, lfilter_zi, sosfiltfilt
from scipy.stats import binomtest

from afmsim.stage import AsymmetricPreisach
from afmsim.workers import available_cores, ordered_map, worker_pool

from ..engine import HONEST_FACTOR, READINGS, STATUSES
from .attribute import diagnose_record
from .distractors import gain_change, mains_pickup, rate_dependent_width, slip
from .null_plants import NULL_FAMILIES, null_plant
from .record import load_record
from .validation import EXCITATIONS, excitation, superpose_steps

__all__ = ["validate_open_world", "headline", "proportion_text", "case_plan", "make_case", "record_drive", "run_case", "score_cases", "proportion", "CaseSpec",
           "PLANTS", "EFFECT_LEVELS", "DISTRACTOR_LEVELS", "DEVELOPMENT_SEEDS", "FRESH_SEEDS", "TARGETS"]

NM_PER_MIN = 1e-9 / 60.0
PLANTS = ("afmsim_preisach", *NULL_FAMILIES)
#: Seeds the suite and the diagnosis were developed on.
DEVELOPMENT_SEEDS = (1, 2, 3, 4, 5, 6)
#: Seeds scored once per frozen version and never developed on: 7001–7003 for the relay baseline of
#: f0a2e4f and again for the resonant dynamics candidate (75110cc); 8001–8003 first for 75110cc and
#: again for the trained-states scoring (d004bf0); 9001–9003 first for d004bf0; 10001–10003 first for
#: the near-noise practical size and the residual noise floor (5de4b49); 11001–11003 first for the
#: full-rate features of decimated records and the Bouc–Wen baseline family (2f3cc21); 12001–12003
#: first for the noise floor where the drive moves least (a37c9db); 13001–13003 first for the family
#: choice that takes the Bouc–Wen law on inner ties (the commit after a37c9db's figures, prompted by
#: two 12001–12003 records); 14001–14003 first for the no-lag dynamics point, the Bouc–Wen shape refitted
#: jointly with the effects and the family choice with nuisance drift and coupling columns (b105495);
#: 15001–15003 first for the block test on informative blocks (6901005; 14001–14003 had shown its case)
#: and again, same method, for the Bouc–Wen plant's corrected integration (013a09c); 16001–16003
#: first for the density prior chosen by inner validation (5913d7e); 17001–17003 first for the pair
#: lookahead of the attribution (4c6d433; 16001–16003 had shown its cases); 18001–18003 first for the
#: fine-play baseline family (0d42b54; Prandtl–Ishlinskii null records outside the suite had shown its case);
#: 19001–19003 first for the drive's relaxation bank in the family check (211fa9a; 18001–18003 had shown its cases);
#: 20001–20003 first for trained states strictly inside the training range (8fee31d;
#: 19001–19003 had shown its case); 21001–21003 first for trained states on the grid continued over the
#: whole record (1702f11; 20001–20003 had shown its case); 22001–22003 first for the block test weighted
#: by each block's gap (f3ef03c; 21001–21003 had shown its case); 23001–23003 first for the fallback
#: scoring that ends at any move beyond the training range (2841b99; 22001–22003 had shown its case);
#: 24001–24003 first for the verdict led by the findings (3d566e7; 23001–23003 had shown its case);
#: 25001–25003 first for the scattered-Preisach plant with jumps below the noise floor (349d92d; a
#: change of the validation plant, measured on spent records of 20001–24003); 26001–26003 first for
#: the 32-level grid with its prior and the family chosen by generalised cross-validation (measured
#: on spent records of 24001–25003); 27001–27003 first for the training-support rule of the
#: attribution (prompted by the null record of tests/test_null_plants.py, seed 2026; measured on spent
#: records of 25001–26003); 28001–28003 first for the Bouc–Wen family's drive term that changes along the
#: voltage (prompted by Coleman–Hodgdon probe records outside the suite; measured on spent records of
#: 27001–27003); 29001–29003 first for the split moved on to held-out states the training part
#: determines (prompted and measured on spent records of 28001–28003); 30001–30003 first for the play
#: family's refined thresholds (1caaf3b; prompted by classical-PI probe records outside the suite,
#: measured on spent records of 29001–29003); 31001–31003 first for the creep bank reaching 10
#: training spans (d1a2311; prompted and measured on spent records of 30001–30003); 32001–32003 first
#: for the prior_dependent reading of the remainder (5908a0a: reporting only, every verdict as
#: before; prompted and measured on spent records of 31001–31003); 33001–33003 first for the resonance
#: under a first-order hold with a Nelder–Mead refinement and the lag grid from 0.03 sample (9059a67;
#: prompted and measured on spent records of 32001–32003); 34001–34003 again for 9059a67's method, its
#: dynamics search sped up, verdicts unchanged and fitted values equal to the last bits (415bbc8);
#: 35001–35003 a third time for that method, its Bouc–Wen search's matrix built once (aae6acc: the same
#: numbers, reports identical on spent records); the untrained_states reading of the remainder came after
#: that run (83b6dfd: reporting only, prompted by two of its nulls); 36001–36003 first for the
#: interior held-out block where no split at the end holds out trained states (41e15a4; prompted by
#: 35001–35003's nulls, measured on spent records of 29001–35003); 37001–37003 again for that
#: method, unchanged (more evidence on the interior block; only docs since 36001–36003's run);
#: 38001–38003 first for a block a tenth long where no fifth is scored in trained states (b94ebf5;
#: prompted by 37001–37003's two largest null gaps, measured on spent records of 29001–37003);
#: 39001–39003 first for two relaxation times per decade in the creep bank (042b429; prompted by
#: 38003/6, measured on spent records of 36001–38003); 40001–40003 first for the dynamics lag in front
#: of the stack and the drift's parabola continued at its final slope (d8947be; prompted by 39003/15
#: and the random walks of 36001–39003, measured on spent records of 36001–39003); 41001–41003 again
#: for d8947be's method (more evidence; since 40001–40003's run only reporting was added — the
#: sensor's noise at rest, the lag-only caveat — and the baseline's least squares moved to a
#: certified solve of the same minimiser, a3f395f, that reproduced all 102 cases of 40001–40003);
#: 42001–42003 a third time for it (more evidence; since 41001–41003's run only review mends, no
#: change to the loop diagnosis); 43001–43003 for the same diagnosis with the suite's random-walk
#: drifts at their labelled size (peak-to-peak excursion = rate × span instead of a least-squares
#: rate, which let 42003/3's "90 nm/min" walk wander by 31.9 µm; :func:`drift_term`); 44001–44003
#: first for loop statuses that also need the training part within 2× (d3be6ed, ``Rules.training_fit``;
#: prompted by spent records of 40001–43003, re-scored on them exactly: no null changed); 45001–45003
#: first for a dynamics lag alone that is not named (``LoopFront.alike_outside``; prompted by the rate
#: widths of 40001–44003 read as lags, measured on their spent records); 46001–46003 first for a
#: drift whose change scales with the displacement that is not named (:mod:`.alike`; prompted by the
#: sensitivity ramps of 40001–45003 read as drifts, measured on their spent records); 47001–47003
#: for that test's revised form (a smooth change in time fitted first, the hysteresis part as the
#: displacement; prompted by the closed suite's largest warm-up drift, measured on the spent records
#: of 40001–46003); 48001–48003 again for it (more evidence; since 47001–47003's run only review
#: mends, no change to the loop diagnosis); 49001–49003 first for a creep that relaxes within a
#: tenth of a second or that a sensitivity change fits as well, not named (:mod:`.alike`; prompted
#: by the rate widths and ramps of 40001–48003 read as creep, measured on their spent records);
#: 50001–50003 again for them (more evidence; since 49001–49003's run only review mends, no change
#: to the loop diagnosis); 51001–51003 first for a dynamics lag alone that competes with a
#: rate-dependent loop width and is named where it fits the training part better (:mod:`.alike`;
#: prompted by the stage modes of 49001–50003 that the drive did not ring, measured on the spent
#: records of 45001–48003); 52001–52003 again for it (more evidence; since 51001–51003's run only
#: its result and docs, no change to the loop diagnosis); 53001–53003 first for the Duhem family's
#: Dahl law and the block-mean backbone of decimated records (:mod:`.bouc_wen`; prompted by Dahl and
#: Coleman–Hodgdon stages outside the suite, development seeds 901–902 of bench_other_families,
#: measured on the spent records of 47001–47003); 54001–54003 first for the sharp-relay family of
#: discrete Preisach stages (:mod:`.sharp_grid`; prompted by sharp-relay stages outside the suite,
#: development seeds 901, 902 and 905, measured on the spent records of 47001–47003: no verdict changed);
#: 55001–55003 first for its fine grids of up to 128 levels and the bar its start must pass
#: (prompted by probe seeds 906–907, measured on the 27 spent records of 47001–47003 and
#: 53001–53003 whose comb stood out: no verdict changed); 56001–56003 first for a dynamics mode the
#: drive never rings, scanned by its inertia (:func:`.model.scan_resonance`; prompted by the
#: resonances under sines that 55001–55003 missed, measured on its spent records and the
#: rate-width distractors of 47001–55003); 57001–57003 first for a drift that a step in time fits as
#: well, withheld as a slip (:func:`.alike.steps_in_time`; prompted by the slip 56001/28
#: explained as a drift, measured on the spent drift, slip, gain-change and null records of 44001–56003);
#: 58001–58003 a second fresh set of the same method (no change since 57001–57003; a probe of the
#: sixteenth session was not taken); 59001–59003 a third, after the seventeenth session's speed-ups
#: (the creep alternation's Gram matrix once a lag, the Bouc–Wen shape search up to the last training
#: sample: the weights equal to rounding, the shape search bit-identical; its probe not taken);
#: 60001–60003 first for the held-out test on the plain likelihood ratio and a creep withheld where
#: a drift fits and predicts as well (:func:`.alike.drifts_in_time`; prompted by the effects 57002/17,
#: 57003/17 and 58001/12 that failed on the parameter charge alone, measured on every spent record of
#: 57001–59003 and the nulls and distractors of 40001–40003 and 56001–56003); 61001–61003 first for
#: held-out scoring within the strict state tolerance (:data:`.model.STRICT_STATE_TOLERANCE`; prompted
#: by the nulls under sines of 60001–60003 above 2×, measured on every spent record of 59001–60003
#: and the nulls of 57001–58003); 62001–62003 a second fresh set of that method (no change since;
#: ``benchmarks/results/open_world_62001-62003.json``, run with ``--seeds``: the default stays the first).
FRESH_SEEDS = (61001, 61002, 61003)
TARGETS = {"effect_top1": 0.9, "null_false_attribution": 0.1, "distractor_false_attribution": 0.1,
           "null_gap_to_noise": HONEST_FACTOR}


@dataclass(frozen=True)
class Level:
    """One injected magnitude: ``value`` (SI), its table label and ``scale`` (datasheet | large)."""

    value: float
    label: str
    scale: str


EFFECT_LEVELS = {
    # datasheet: 1–10 nm/min after warm-up, 10–50 nm/min just after start; plausible bound 100 nm/min
    "drift": (Level(3 * NM_PER_MIN, "3 nm/min", "datasheet"), Level(10 * NM_PER_MIN, "10 nm/min", "datasheet"),
              Level(40 * NM_PER_MIN, "40 nm/min", "datasheet"), Level(90 * NM_PER_MIN, "90 nm/min", "large")),
    # datasheet γ = 1–2 %/decade; plausible bound 3 %/decade
    "creep": (Level(0.01, "1 %/decade", "datasheet"), Level(0.015, "1.5 %/decade", "datasheet"),
              Level(0.02, "2 %/decade", "datasheet"), Level(0.028, "2.8 %/decade", "large")),
    # datasheet 0.1–1 % (flexures), several % (tubes); plausible bound 5 %
    "cross_coupling": (Level(0.001, "0.1 %", "datasheet"), Level(0.003, "0.3 %", "datasheet"),
                       Level(0.01, "1 %", "datasheet"), Level(0.03, "3 %", "large")),
    # resonance f0 (Hz); datasheet 300 Hz–3 kHz; the large case adds a 60 Hz amplifier pole (lag 2.7 ms ≤ 5 ms)
    "dynamics": (Level(3000.0, "f0 3 kHz", "datasheet"), Level(1000.0, "f0 1 kHz", "datasheet"),
                 Level(300.0, "f0 300 Hz", "datasheet"), Level(300.0, "f0 300 Hz + 60 Hz amplifier pole", "large")),
}
LARGE_AMPLIFIER_POLE_HZ = 60.0
DISTRACTOR_LEVELS = {
    "mains": (Level(5e-9, "5 nm", "small"), Level(30e-9, "30 nm", "large")),            # sine amplitude (m)
    "slip": (Level(40e-9, "40 nm", "small"), Level(400e-9, "400 nm", "large")),          # step size (m)
    "gain_change": (Level(0.005, "0.5 %", "small"), Level(0.02, "2 %", "large")),        # sensitivity change
    "rate_width": (Level(0.003, "0.3 % of travel", "small"), Level(0.02, "2 % of travel", "large")),  # half-width
}
PAIRS = ((("drift", 3), ("cross_coupling", 2)), (("creep", 3), ("dynamics", 2)))
TIMING_OF_EFFECT = {"drift": "long", "creep": "standard", "cross_coupling": "standard", "dynamics": "fast"}
TIMINGS = ("standard", "long", "fast")


@dataclass(frozen=True)
class CaseSpec:
    """One planned case: ``category`` (effect | null | distractor), the injected ``effects``
    (``(name, level index)`` pairs), the ``distractor`` (``(name, level index)``) and, for nulls,
    the ``plant`` (others draw theirs)."""

    category: str
    effects: tuple = ()
    distractor: tuple | None = None
    plant: str | None = None


def case_plan() -> list[CaseSpec]:
    """The cases of one seed (34): every effect at its 4 levels, 2 pairs, 2 nulls per plant
    family, every distractor at its 2 levels."""
    plan = [CaseSpec("effect", ((name, k),)) for name, levels in EFFECT_LEVELS.items() for k in range(len(levels))]
    plan += [CaseSpec("effect", pair) for pair in PAIRS]
    plan += [CaseSpec("null", plant=p) for p in PLANTS for _ in range(2)]
    plan += [CaseSpec("distractor", distractor=(d, k)) for d, levels in DISTRACTOR_LEVELS.items()
             for k in range(len(levels))]
    return plan


def _timing(spec: CaseSpec, rng: np.random.Generator) -> str:
    names = [e for e, _ in spec.effects]
    if "dynamics" in names:
        return "fast"
    if names:
        return "long" if "drift" in names else TIMING_OF_EFFECT[names[0]]
    return TIMINGS[int(rng.integers(len(TIMINGS)))]


def _repeats_its_range(v: np.ndarray, train_fraction: float = 0.6, tolerance: float = 0.01) -> bool:
    """Whether the held-out part of a drive stays inside the training part's voltage range (the
    diagnosis protocol: relays only the held-out part switches cannot be known)."""
    k = int(round(train_fraction * v.size))
    lo, hi = float(v[:k].min()), float(v[:k].max())
    pad = tolerance * (hi - lo)
    return bool(v[k:].min() >= lo - pad and v[k:].max() <= hi + pad)


def record_drive(timing: str, rng: np.random.Generator, f0: float | None = None) -> tuple[np.ndarray, np.ndarray, str]:
    """Time (s), drive voltage (0–10 V) and excitation kind of one record, redrawn (up to 100 times)
    until its held-out part repeats the training part's voltage range."""
    if timing == "fast":
        f0 = f0 if f0 is not None else float(rng.choice([300.0, 1000.0, 3000.0]))
    for _ in range(100):
        kind = EXCITATIONS[int(rng.integers(len(EXCITATIONS)))]
        if timing == "fast":
            fs = float(np.clip(10.0 * f0, 3000.0, 20000.0))
            _, v = excitation(kind, 1000.0, 8.0, rng)  # the path of a 1 kHz, 8 s record, played fs/1 kHz faster
            t = np.arange(v.size) / fs
        elif timing == "long":
            t, v = excitation(kind, float(rng.choice([200.0, 500.0, 1000.0])), float(rng.uniform(30.0, 60.0)), rng)
        else:
            t, v = excitation(kind, float(rng.choice([500.0, 1000.0, 2000.0])), float(rng.uniform(8.0, 16.0)), rng)
        if _repeats_its_range(v):
            return t, v, kind
    raise RuntimeError("no drive in 100 draws repeats its voltage range in the held-out part")


def _cross_drive(t, timing: str, rng: np.random.Generator) -> np.ndarray:
    """A drive (V) of the cross axis with the same samples as ``t`` (its own excitation kind)."""
    kind = EXCITATIONS[int(rng.integers(len(EXCITATIONS)))]
    fs = 1000.0 if timing == "fast" else 1.0 / float(t[1] - t[0])  # fast: the 1 kHz path, played faster
    return excitation(kind, fs, t.size / fs, rng)[1]


def plant_displacement(plant: str, v: np.ndarray, plant_seed: int) -> np.ndarray:
    """Displacement (m) of ``plant`` (a key of :data:`PLANTS`) for the drive ``v`` (V);
    ``plant_seed`` draws the other families' shapes (afmsim's own stage is fixed)."""
    if plant == "afmsim_preisach":
        return AsymmetricPreisach().apply(np.clip(v, 0.0, 10.0))
    return null_plant(plant, v, np.random.default_rng(plant_seed))


def creep_term(t, h, gamma: float, form: str, rng: np.random.Generator) -> np.ndarray:
    """Creep (m) of the hysteresis output ``h``: log-law or stretched-exponential step responses
    scaled so that the unit step's rise between 0.1 s and 10 s is ``gamma`` per decade."""
    if form == "log":
        tau0 = rng.uniform(0.005, 0.05)
        shape = lambda s: np.log10(1.0 + s / tau0)  # noqa: E731
    else:
        tau, beta = rng.uniform(1.0, 20.0), rng.uniform(0.3, 0.6)
        shape = lambda s: 1.0 - np.exp(-np.power(np.maximum(s, 0.0) / tau, beta))  # noqa: E731
    a = 2.0 * gamma / float(shape(10.0) - shape(0.1))
    return superpose_steps(t, h, lambda s: a * shape(s))


def drift_term(t, rate: float, form: str, rng: np.random.Generator) -> np.ndarray:
    """Drift (m) of magnitude ``rate`` (m/s): an exponential warm-up whose least-squares rate over
    the record is ``rate``, or a smooth random walk (integrated noise low-passed at 3–10 cycles per
    record) that wanders by ``|rate|`` × the record's span peak to peak — what a steady drift at
    the datasheet's rate covers in that time. Until 43001–43003 the walk too was scaled to a
    least-squares rate, which a walk that wanders back barely has: on the walk records of
    40001–42003 it wandered by 1–400× the label × the span (42003/3: 31.9 µm for "90 nm/min" over
    53 s), far beyond a datasheet drift (docs/diagnosis.md, "Random-walk drifts at their labelled size")."""
    s = t - t[0]
    span = float(s[-1])
    if form == "warmup":
        shape = 1.0 - np.exp(-s / (rng.uniform(0.3, 2.0) * span))
    else:
        fs = 1.0 / float(s[1])
        sos = butter(2, min(rng.uniform(3.0, 10.0) / span, 0.4 * fs), fs=fs, output="sos")
        shape = np.cumsum(sosfiltfilt(sos, rng.standard_normal(s.size)))
        return (shape - shape[0]) * (rate * span * rng.choice([-1.0, 1.0]) / np.ptp(shape))
    slope = float(np.polyfit(s, shape, 1)[0])
    return shape * (rate * rng.choice([-1.0, 1.0]) / slope)


def _bilinear_filter(num, den, fs, u):
    """``u`` through the continuous transfer function num/den (bilinear transform at ``fs``),
    starting in steady state at ``u[0]``."""
    b, a = bilinear(num, den, fs)
    return lfilter(b, a, u, zi=lfilter_zi(b, a) * u[0])[0]


def _prewarped(f_hz: float, fs: float) -> float:
    """Angular frequency (rad/s) that the bilinear transform at ``fs`` maps onto ``f_hz`` exactly."""
    return 2.0 * fs * np.tan(np.pi * f_hz / fs)


def amplifier(v, fs: float, pole_hz: float) -> np.ndarray:
    """Voltage (V) after a first-order high-voltage amplifier pole ω/(s + ω), discretised exactly
    for a piecewise-linear input (first-order hold; stable for a pole beyond Nyquist too),
    starting in steady state at the first sample."""
    w = 2 * np.pi * pole_hz
    b, a, _ = cont2discrete(([w], [1.0, w]), 1.0 / fs, method="foh")
    b = np.ravel(b)
    return lfilter(b, a, v, zi=lfilter_zi(b, a) * v[0])[0]


def resonance(x, fs: float, f0: float, zeta: float) -> np.ndarray:
    """Displacement (m) through ω0²/(s² + 2ζω0 s + ω0²) (bilinear transform, pre-warped at f0),
    starting in steady state at the first sample."""
    w0 = _prewarped(f0, fs)
    return _bilinear_filter([w0 * w0], [1.0, 2 * zeta * w0, w0 * w0], fs, x)


def make_case(spec: CaseSpec, rng: np.random.Generator) -> dict:
    """Simulate one case: the record's columns, the same record without the injected effect or
    distractor (``reference``, for the oracle), and what was injected."""
    plant = spec.plant or PLANTS[int(rng.integers(len(PLANTS)))]
    names = dict(spec.effects)
    f0 = EFFECT_LEVELS["dynamics"][names["dynamics"]].value if "dynamics" in names else None
    timing = _timing(spec, rng)
    t, v, kind = record_drive(timing, rng, f0)
    fs = 1.0 / float(t[1] - t[0])
    plant_seed = int(rng.integers(2**63))
    h_ref = plant_displacement(plant, v, plant_seed)
    sigma = float(rng.uniform(5e-9, 15e-9))
    injected = []
    x = h_ref
    if "dynamics" in names:
        level = EFFECT_LEVELS["dynamics"][names["dynamics"]]
        pole = LARGE_AMPLIFIER_POLE_HZ if level.scale == "large" else level.value * rng.uniform(3.0, 10.0)
        zeta = float(rng.uniform(0.01, 0.05))
        x = plant_displacement(plant, amplifier(v, fs, pole), plant_seed)
        dynamics = {"effect": "dynamics", "form": "amplifier pole + resonance", "f0_hz": level.value,
                    "amplifier_pole_hz": float(pole), "zeta": zeta}
        injected.append(dynamics)
    if "creep" in names:
        level = EFFECT_LEVELS["creep"][names["creep"]]
        form = ("log", "stretched")[int(rng.integers(2))]
        x = x + creep_term(t, x, level.value, form, rng)
        injected.append({"effect": "creep", "form": form, "gamma_per_decade": level.value})
    if "dynamics" in names:
        x = resonance(x, fs, dynamics["f0_hz"], dynamics["zeta"])
    has_y = "cross_coupling" in names or rng.random() < 0.5
    y_true = None
    if has_y:
        y_true = plant_displacement(plant, _cross_drive(t, timing, rng), int(rng.integers(2**63)))
    if "cross_coupling" in names:
        level = EFFECT_LEVELS["cross_coupling"][names["cross_coupling"]]
        q = float(rng.uniform(-0.3, 0.3))
        x = x + level.value * (y_true + q * (y_true - y_true.mean()) ** 2 / np.ptp(y_true))
        injected.append({"effect": "cross_coupling", "form": "true y + quadratic arc", "coefficient": level.value,
                         "arc": q})
    if "drift" in names:
        level = EFFECT_LEVELS["drift"][names["drift"]]
        form = ("warmup", "walk")[int(rng.integers(2))]
        x = x + drift_term(t, level.value, form, rng)
        injected.append({"effect": "drift", "form": form, "rate_m_per_s": level.value})
    noise = sigma * rng.standard_normal(t.size)
    x_ref = h_ref + noise
    x_m = x + noise
    if spec.distractor is not None:
        name, k = spec.distractor
        level = DISTRACTOR_LEVELS[name][k]
        span = float(t[-1] - t[0])
        info = {"distractor": name, "value": level.value, "label": level.label}
        if name == "mains":
            freq = float(rng.choice([50.0, 60.0]))
            x_m = x_m + mains_pickup(t, level.value, freq, rng)
            info["frequency_hz"] = freq
        elif name == "slip":
            at = float(t[0] + rng.uniform(0.15, 0.85) * span)
            x_m = x_m + slip(t, level.value * rng.choice([-1.0, 1.0]), at)
            info["at_s"] = at
        elif name == "gain_change":
            start = float(t[0] + rng.uniform(0.1, 0.6) * span)
            end = start + rng.uniform(0.2, 0.4) * span
            x_m = gain_change(t, x_m, level.value * rng.choice([-1.0, 1.0]), start, end)
            info.update(start_s=start, end_s=end)
        else:
            x_m = x_m + rate_dependent_width(t, v, level.value * np.ptp(h_ref))
        injected.append(info)
    v_rec = 30.0 * (v - 5.0) if rng.random() < 0.35 else v  # unit/offset invariance
    cols = {"t_s": t, "v_V": v_rec, "x_m": x_m}
    if has_y:
        cols["y_m"] = y_true + sigma * rng.standard_normal(t.size)
    return {"columns": cols, "reference_x_m": x_ref, "plant": plant, "timing": timing, "excitation": kind, "fs": fs,
            "sigma": sigma, "injected": injected}


def _labels(spec: CaseSpec) -> dict:
    out = {"category": spec.category, "effects": [e for e, _ in spec.effects],
           "levels": {e: EFFECT_LEVELS[e][k].label for e, k in spec.effects},
           "scales": {e: EFFECT_LEVELS[e][k].scale for e, k in spec.effects}}
    if spec.distractor is not None:
        name, k = spec.distractor
        out.update(distractor=name, distractor_level=DISTRACTOR_LEVELS[name][k].label,
                   distractor_scale=DISTRACTOR_LEVELS[name][k].scale)
    return out


def run_case(seed: int, index: int) -> dict:
    """Simulate and diagnose case ``index`` of :func:`case_plan` for ``seed``; a JSON-able result."""
    spec = case_plan()[index]
    case = make_case(spec, np.random.default_rng([seed, index]))
    out = {"seed": seed, "index": index, **_labels(spec), "plant": case["plant"], "timing": case["timing"],
           "excitation": case["excitation"], "fs": case["fs"], "injected": case["injected"]}
    t0 = time.perf_counter()
    try:
        rec = load_record(case["columns"])
        rep, _, _ = diagnose_record(rec)
        ref_cols = {**case["columns"], "x_m": case["reference_x_m"]}
        ref, _, _ = diagnose_record(load_record(ref_cols), candidates=[])
    except ValueError as error:
        return {**out, "error": str(error).splitlines()[0], "seconds": round(time.perf_counter() - t0, 2)}
    sigma = rep["baseline"]["noise_floor"]
    added = rep["baseline"]["rms_gap"] ** 2 - ref["baseline"]["rms_gap"] ** 2
    true = out["effects"]
    out.update({
        "samples": rec.n, "decimation": rec.decimation, "verdict": rep["verdict"], "findings": rep["findings"],
        "status": rep["status"], "gap_to_noise": rep["baseline"]["gap_to_noise"],
        "final_gap_to_noise": rep["unexplained"]["gap_to_noise"],
        "final_train_gap_to_noise": rep["unexplained"].get("train_gap_to_noise"),
        "reading": rep["unexplained"].get("reading"),
        "prior_spread_to_noise": rep["baseline"]["prior_spread_to_noise"],
        "reference_gap_to_noise": ref["baseline"]["gap_to_noise"],
        "implausible": [f["effect"] for f in rep["implausible"]],
        # oracle: the injected term raises the baseline's held-out mean square by ≥ σ²
        "visible": bool(added >= sigma**2), "added_gap_to_noise": round(float(np.sqrt(max(added, 0.0))) / sigma, 3),
        "seconds": round(time.perf_counter() - t0, 2)})
    if true:
        out["top1"] = bool(rep["verdict"]) and rep["verdict"][0] in true
        out["exact"] = set(rep["verdict"]) == set(true)
        out["detected"] = {e: e in rep["verdict"] for e in true}
    return out


def wilson(k: int, n: int) -> list[float] | None:
    """Wilson 95 % interval of the proportion k/n (None when n = 0)."""
    if n == 0:
        return None
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=0.95, method="wilson")
    return [round(float(ci.low), 4), round(float(ci.high), 4)]


def proportion(flags) -> dict:
    """``{"k", "n", "rate", "ci95"}`` of a list of booleans (rate None when empty)."""
    flags = [bool(f) for f in flags]
    k, n = sum(flags), len(flags)
    return {"k": k, "n": n, "rate": round(k / n, 4) if n else None, "ci95": wilson(k, n)}


def _level_order(effect: str) -> list[str]:
    return [lv.label for lv in EFFECT_LEVELS[effect]]


def score_cases(results: list[dict]) -> dict:
    """Scores of a list of :func:`run_case` results (cases with an ``error`` are counted apart)."""
    ok = [r for r in results if "error" not in r]
    eff = [r for r in ok if r["category"] == "effect"]
    nulls = [r for r in ok if r["category"] == "null"]
    dis = [r for r in ok if r["category"] == "distractor"]
    visible = [r for r in eff if r["visible"]]
    detection = {}
    for effect in EFFECT_LEVELS:
        rows = {}
        for label in _level_order(effect):
            sub = [r for r in eff if r["effects"] == [effect] and r["levels"][effect] == label]
            if sub:
                rows[label] = {"scale": sub[0]["scales"][effect], "detected": proportion(r["detected"][effect] for r in sub),
                               "top1": proportion(r["top1"] for r in sub), "visible": sum(r["visible"] for r in sub),
                               "detected_when_visible": proportion(r["detected"][effect] for r in sub if r["visible"])}
        detection[effect] = rows
    null_gaps = {}
    for plant in PLANTS:
        gaps = [r["gap_to_noise"] for r in nulls if r["plant"] == plant]
        if gaps:
            null_gaps[plant] = {"n": len(gaps), "median": round(float(np.median(gaps)), 3),
                                "max": round(float(np.max(gaps)), 3),
                                "within_2x": proportion(g <= HONEST_FACTOR for g in gaps), "values": gaps}
    distractors = {}
    for name in DISTRACTOR_LEVELS:
        sub = [r for r in dis if r["distractor"] == name]
        if sub:
            distractors[name] = {"false_attribution": proportion(bool(r["verdict"]) for r in sub),
                                 "explained": proportion(r["status"] == "explained" for r in sub),
                                 "status_counts": {s: sum(r["status"] == s for r in sub) for s in STATUSES},
                                 "verdicts": [r["verdict"] for r in sub]}
    scores = {
        "cases": len(results), "errors": len(results) - len(ok),
        "effect_top1": proportion(r["top1"] for r in eff),
        "effect_exact_set": proportion(r["exact"] for r in eff),
        "effect_top1_visible": proportion(r["top1"] for r in visible),
        "effect_exact_set_visible": proportion(r["exact"] for r in visible),
        "effect_top1_datasheet": proportion(r["top1"] for r in eff if set(r["scales"].values()) == {"datasheet"}),
        "null_false_attribution": proportion(bool(r["verdict"]) for r in nulls),
        "null_explained": proportion(r["status"] == "explained" for r in nulls),
        "null_false_findings": proportion(bool(r["findings"]) for r in nulls),
        "distractor_false_attribution": proportion(bool(r["verdict"]) for r in dis),
        "distractor_explained": proportion(r["status"] == "explained" for r in dis),
        "distractor_false_findings": proportion(bool(r["findings"]) for r in dis),
        "null_gap_to_noise": null_gaps,
        "nulls_within_2x": proportion(r["gap_to_noise"] <= HONEST_FACTOR for r in nulls),
        "null_gap_to_noise_by_excitation": {
            kind: {"n": len(g), "median": round(float(np.median(g)), 3), "max": round(float(np.max(g)), 3)}
            for kind in EXCITATIONS if (g := [r["gap_to_noise"] for r in nulls if r.get("excitation") == kind])},
        "status_counts": {cat: {s: sum(r["status"] == s for r in ok if r["category"] == cat) for s in STATUSES}
                          for cat in ("effect", "null", "distractor")},
        # above 2x: does the final model miss its own training part too (capacity), or the held-out part only?
        "null_readings": {plant: {reading: sum(r.get("reading") == reading for r in nulls if r["plant"] == plant)
                                  for reading in READINGS}
                          for plant in dict.fromkeys(r["plant"] for r in nulls)},
        # the same readings of the remainder on effect and distractor records (prior_dependent: the gap left
        # is no larger than what the training part leaves to the grid's prior)
        "remainder_readings": {cat: {reading: sum(r.get("reading") == reading for r in group) for reading in READINGS}
                               for cat, group in (("effect", eff), ("distractor", dis))},
        "detection_vs_magnitude": detection,
        "distractors": distractors,
    }
    top1, fa_n, fa_d = scores["effect_top1"]["rate"], scores["null_false_attribution"]["rate"], \
        scores["distractor_false_attribution"]["rate"]
    scores["targets"] = TARGETS
    scores["targets_met"] = {
        "effect_top1": top1 is not None and top1 >= TARGETS["effect_top1"],
        "null_false_attribution": fa_n is not None and fa_n <= TARGETS["null_false_attribution"],
        "distractor_false_attribution": fa_d is not None and fa_d <= TARGETS["distractor_false_attribution"],
        "null_gap_to_noise": bool(nulls) and all(r["gap_to_noise"] <= HONEST_FACTOR for r in nulls)}
    return scores


def validate_open_world(seeds=FRESH_SEEDS, *, workers: int | None = None, on_done=None) -> dict:
    """Run :func:`case_plan` for every seed (cases spread over ``workers`` processes, default: every
    core) and score them pooled and per seed. ``on_done(index, done, total)`` reports progress."""
    seeds = [int(s) for s in seeds]
    if not seeds or any(s < 0 for s in seeds):
        raise ValueError(f"seeds must be one or more integers >= 0, got {seeds}")
    n = len(case_plan())
    items = [(seed, i) for seed in seeds for i in range(n)]
    t0 = time.perf_counter()
    with worker_pool(workers or available_cores()) as executor:
        results = ordered_map(executor, run_case, items, on_done)
    return {"suite": "open-world", "seeds": seeds, "development_seeds": list(DEVELOPMENT_SEEDS),
            "fresh": all(s not in DEVELOPMENT_SEEDS for s in seeds), "cases_per_seed": n,
            "wall_s": round(time.perf_counter() - t0, 1), "scores": score_cases(results),
            "by_seed": {str(s): score_cases([r for r in results if r["seed"] == s]) for s in seeds},
            "cases": results}


def proportion_text(p: dict) -> str:
    """A :func:`proportion` as ``"75% (3/4; 30%–95%)"`` (rate, k/n, Wilson 95 % interval)."""
    if p["rate"] is None:
        return "n/a (no cases)"
    lo, hi = p["ci95"]
    return f"{p['rate']:.0%} ({p['k']}/{p['n']}; {lo:.0%}–{hi:.0%})"


def headline(result: dict) -> dict:
    """The headline figures of :func:`validate_open_world`'s result, one line each (for the CLI)."""
    s = result["scores"]
    gaps = s["null_gap_to_noise"]
    return {"suite": "open-world", "seeds": ",".join(map(str, result["seeds"])),
            "seeds_fresh": result["fresh"], "cases": s["cases"], "errors": s["errors"],
            "effect_top1": proportion_text(s["effect_top1"]), "effect_exact_set": proportion_text(s["effect_exact_set"]),
            "effect_top1_visible": proportion_text(s["effect_top1_visible"]),
            "null_false_attribution": proportion_text(s["null_false_attribution"]),
            "distractor_false_attribution": proportion_text(s["distractor_false_attribution"]),
            "distractor_explained": proportion_text(s["distractor_explained"]),
            "nulls_within_2x_noise": proportion_text(s["nulls_within_2x"]),
            "null_gap_to_noise_max": ", ".join(f"{p} {g['max']:.1f}x" for p, g in gaps.items()),
            "targets_met": ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in s["targets_met"].items()),
            "wall_s": result["wall_s"]}
