"""The loop diagnosis baseline (afmsim.diagnosis.loops.model): its capacity and family chosen inside
the training part, the smoothness prior on the relay density, full-rate hysteresis for decimated
records, and which held-out samples are scored."""

import numpy as np
import pytest

from afmsim.diagnosis.engine import noise_floor
from afmsim.diagnosis.loops.attribute import choose_split, diagnose_record
from afmsim.diagnosis.loops.model import (MIN_SCORED, N_LEVELS, SEARCH_LEVELS, SMOOTHING_CHOICES, STATE_TOLERANCE,
                                          STRICT_SHARE, STRICT_STATE_TOLERANCE, Design, ModelSpec, _filt, _fit_columns,
                                          after_excursion, fit_model, lag_filter, relay_curvature, relay_features,
                                          solve_weights, untrained_state)
from afmsim.diagnosis.loops.null_plants import _relay_sum, null_plant, scattered_preisach
from afmsim.diagnosis.loops.open_world import case_plan, make_case
from afmsim.diagnosis.loops.record import load_record
from afmsim.diagnosis.loops.validation import excitation
from afmsim.stage import AsymmetricPreisach


def _drive(seed=0):
    t, v = excitation("triangles", 500.0, 12.0, np.random.default_rng(seed))
    return t, v, np.arange(t.size) < int(0.6 * t.size)


def _record(hysteresis, v, rng):
    """1e-5 m/V linear part + 2 µm of the given relay sum + 5 nm noise."""
    return 1e-5 * v + 2e-6 * hysteresis / np.ptp(hysteresis) + 5e-9 * rng.standard_normal(v.size)


@pytest.mark.parametrize("seed", [0, 2, 4])
def test_the_default_grid_follows_sharp_relays_closer_than_a_coarse_one(seed):
    """60 sharp relays at random thresholds (steps that a 0.6 V-wide smoothed relay cannot follow):
    the default grid (N_LEVELS, 32 levels over the training range) leaves a held-out RMS gap
    at least 15 % smaller than the 16-level grid the baseline used before (22–31 % on these seeds)."""
    t, v, train = _drive(seed)
    rng = np.random.default_rng(seed + 1)
    up = rng.uniform(1.0, 9.0, 60)
    x = _record(_relay_sum(v, up, up - rng.uniform(0.2, 2.0, 60), np.ones(60)), v, rng)
    gaps = {}
    for n_levels in (None, 16):
        d = Design(t, v, x, None, train, n_levels=n_levels)
        held, _ = d.scored()
        gaps[d.n_levels] = float(np.sqrt(np.mean((x - fit_model(d, ModelSpec()).prediction)[held] ** 2)))
    assert set(gaps) == {N_LEVELS, 16}
    assert gaps[N_LEVELS] < 0.85 * gaps[16], gaps


def test_the_lag_is_searched_on_the_coarse_grid_and_fitted_on_the_records():
    """A 5 ms first-order lag after 200 sharp relays: the dynamics candidate finds the delay
    (τ plus the zero-order hold's half sample) on the SEARCH_LEVELS grid — the lag the 16-level
    grid finds — and fits it with the record's 32-level grid (its parameter count)."""
    t, v, train = _drive(6)
    rng = np.random.default_rng(7)
    up = rng.uniform(1.0, 9.0, 200)
    h = _relay_sum(v, up, up - rng.uniform(0.2, 2.0, 200), np.ones(200))
    dt = float(t[1] - t[0])
    x = _filt(*lag_filter(5e-3, dt), (1e-5 * v + 2e-6 * h / np.ptp(h))[:, None])[:, 0] + 5e-9 * rng.standard_normal(v.size)
    d = Design(t, v, x, None, train)
    fitted = fit_model(d, ModelSpec(effects=("dynamics",)))
    width = d.n_levels + 1
    assert d.n_levels > SEARCH_LEVELS and fitted.n_params == 2 + width * (width + 1) // 2 + 2
    delay = fitted.params["dynamics"]["lag_time_constant_s"]
    assert delay == pytest.approx(5e-3 + 0.5 * dt, rel=0.1)
    coarse = Design(t, v, x, None, train, n_levels=SEARCH_LEVELS)
    coarse.smoothing = d.smoothing
    assert fit_model(coarse, ModelSpec(effects=("dynamics",))).params["dynamics"] == fitted.params["dynamics"]


def test_grid_choice_never_sees_the_heldout_part():
    t, v, train = _drive(2)
    rng = np.random.default_rng(3)
    up = rng.uniform(1.0, 9.0, 60)
    x = _record(_relay_sum(v, up, up - rng.uniform(0.2, 2.0, 60), np.ones(60)), v, rng)
    spoiled = x.copy()
    spoiled[~train] += 1e-5 * rng.standard_normal(int((~train).sum()))  # 10 µm of garbage after the split
    a, b = Design(t, v, x, None, train), Design(t, v, spoiled, None, train)
    assert a.n_levels == b.n_levels and a.choice_scores == b.choice_scores
    assert a.family == b.family and "gcv_preisach" in a.choice_scores  # the family check's scores included


def test_the_effective_parameter_count_is_the_column_count_less_what_the_prior_and_constraints_take():
    """solve_weights(with_df=True): a plain fit with every positive weight free of its bound has
    df = its column count (less the tiny ridge's share); a weight the data push below 0 sits on
    its bound and no longer counts; a stiff second-difference prior on the positive weights leaves
    only its null space, a straight line (2) besides the free columns."""
    rng = np.random.default_rng(0)
    m, n_free, n_pos = 2000, 2, 10
    free = np.column_stack([np.ones(m), rng.standard_normal(m)])
    pos = rng.uniform(0.0, 1.0, (m, n_pos))
    mask = np.ones(m, dtype=bool)
    weights = np.linspace(1.0, 2.0, n_pos)
    x = free @ [0.3, -0.2] + pos @ weights + 0.01 * rng.standard_normal(m)
    *_, df = solve_weights(free, pos, x, mask, with_df=True)
    assert df == pytest.approx(n_free + n_pos, abs=1e-3)
    pushed = weights.copy()
    pushed[4] = -1.0
    *_, df = solve_weights(free, pos, free @ [0.3, -0.2] + pos @ pushed + 0.01 * rng.standard_normal(m), mask, with_df=True)
    assert df == pytest.approx(n_free + n_pos - 1, abs=1e-3)
    second_differences = np.diff(np.eye(n_pos), n=2, axis=0)
    *_, df = solve_weights(free, pos, x, mask, smooth=second_differences, smoothing=1e4, with_df=True)
    assert n_free + 2 - 1e-3 < df < n_free + 2.1


def test_curvature_prior_is_free_for_a_linear_density_only():
    n = 9
    i, j = np.tril_indices(n)  # the relay order of relay_features: (i, j <= i), row by row
    d = relay_curvature(n)
    assert d.shape[1] == n * (n + 1) // 2
    assert np.allclose(d @ (0.3 + 0.2 * i - 0.1 * j), 0.0)
    assert np.linalg.norm(d @ (i - j) ** 2.0) > 1.0


def test_heldout_scoring_stops_at_the_first_excursion_beyond_the_training_range():
    v = np.r_[np.linspace(0, 8, 600), np.linspace(8, 0, 400), np.linspace(0, 7, 300), np.linspace(7, 9, 100),
              np.linspace(9, 1, 600)]
    train = np.arange(v.size) < 1000
    out = after_excursion(v, train)
    first = 1300 + int(np.argmax(v[1300:] > 8.08))
    assert not out[:first].any() and out[first:].all()
    t = np.arange(v.size) * 1e-3
    d = Design(t, v, 1e-5 * v, None, train, n_levels=16)
    scored, rule = d.scored()
    # the fallback ends at the first move beyond the training range, within the tolerance or not
    strictly = 1300 + int(np.argmax(v[1300:] > 8.0))
    assert strictly < first
    assert rule == "before_excursion" and scored.sum() == strictly - 1000
    # an excursion right after the split leaves fewer than 50 samples: every in-range sample counts
    v = np.r_[np.linspace(0, 8, 600), np.linspace(8, 9, 100), np.linspace(9, 0, 600)]
    train = np.arange(v.size) < 600
    d = Design(np.arange(v.size) * 1e-3, v, 1e-5 * v, None, train, n_levels=16)
    scored, rule = d.scored()
    assert rule == "in_range" and scored.sum() == int(np.sum(~train & (v <= 8.08))) > 500
    # coming back to the range's other end does not wipe an excursion above it out: relays it
    # switched on whose down-threshold lies below the range (the grid's level below it) stay on
    v = np.r_[v, np.linspace(0, 7, 300)]
    train = np.arange(v.size) < 600
    first = 600 + int(np.argmax(v[600:] > 8.08))
    assert after_excursion(v, train).sum() == v.size - first
    d = Design(np.arange(v.size) * 1e-3, v, 1e-5 * v, None, train, n_levels=16)
    scored, rule = d.scored()
    assert rule == "in_range" and scored[-300:].all()
    # an excursion below the range is wiped out once the voltage climbs back past the up-thresholds
    # of every relay it switched off (the range's top): the climb itself is no trained state (relays
    # with down-thresholds between 1 V and 3 V are off, those below 1 V on: the training part never
    # told them apart), the descent and the next climb from the top on are, and are scored
    cycle = np.r_[np.linspace(3, 8, 300), np.linspace(8, 3, 300)]
    v = np.r_[cycle, cycle, np.linspace(3, 1, 100), np.linspace(1, 8, 350), cycle[300:], cycle[:300]]
    train = np.arange(v.size) < 1200
    d = Design(np.arange(v.size) * 1e-3, v, 1e-5 * v, None, train, n_levels=16)
    scored, rule = d.scored()
    below = 1200 + int(np.argmax(v[1200:] < 2.95))  # the excursion leaves the range (1 % tolerance)
    top = 1650  # the climb back reaches 8 V
    assert rule == "wiped_excursions"
    assert not scored[below:top - 20].any()
    assert scored[top:].mean() > 0.95


def test_heldout_states_the_training_part_never_determined_are_not_scored():
    # training: up from rest to 9 V, then loops between 9 V and 4 V; held out: the same loops, then a
    # descent to 1 V and back. Relays with down-thresholds below 4 V were switched on together on the
    # first rise and never off: the descent switches them off one by one, with weights no training
    # sample determined, although every voltage lies inside the training range.
    loop = np.r_[np.linspace(9, 4, 200), np.linspace(4, 9, 200)]
    v = np.r_[np.linspace(0, 9, 300), np.tile(loop, 4), np.tile(loop, 2), np.linspace(9, 1, 400), np.linspace(1, 9, 400)]
    train = np.arange(v.size) < 1900
    t = np.arange(v.size) * 1e-3
    rng = np.random.default_rng(7)
    up = rng.uniform(0.5, 9.0, 80)
    x = _record(_relay_sum(v, up, up - rng.uniform(0.2, 4.0, 80), rng.uniform(0.5, 1.5, 80)), v, rng)
    d = Design(t, v, x, None, train, n_levels=16)
    scored, rule = d.scored()
    descent = np.arange(v.size) >= 2700
    assert rule == "trained_states"
    assert scored[1900:2700].mean() > 0.9  # the repeated loops count
    assert not scored[descent & (v < 3.5)].any()  # below every training reversal: not determined
    assert scored[-5:].all()  # back at 9 V: every relay is on again, as in training
    # the excluded states are where a rate-independent fit goes wrong, the scored ones are not
    r = x - fit_model(d, ModelSpec()).prediction
    untrained = ~train & ~scored
    assert np.sqrt(np.mean(r[untrained] ** 2)) > 3 * np.sqrt(np.mean(r[scored] ** 2))


def test_a_held_out_step_just_above_the_training_range_is_not_a_trained_state():
    """A held-out step 0.06 V above the training part's highest voltage lies within the 1 % range
    tolerance, but there the grid's relays are clipped (all on) while the stage's next ones still
    switch: the trained-states rule leaves it out (``before_excursion`` still counts it)."""
    cycle = np.r_[0.5, 8.0, 2.0, 6.0, 1.0, 7.0, 3.0]
    v = np.repeat(np.r_[cycle, cycle, cycle[0], 8.06, cycle[2:]], 200)  # held out: the cycle, 8.06 V for 8 V
    train = np.arange(v.size) < 2 * cycle.size * 200
    d = Design(np.arange(v.size) * 1e-3, v, 1e-5 * v, None, train, n_levels=16)
    scored, rule = d.scored()
    above = v > 8.0
    assert d.in_range[above].all()  # inside the tolerance
    assert rule == "trained_states" and not scored[above].any() and scored[~train & ~above].any()


def test_relays_switched_just_above_the_training_range_stay_untrained_until_switched_back():
    """A null record of afmsim's stage under band-limited noise (open-world seed 20003, case 19,
    spent): a held-out move 0.1 V above the training range, inside the 1 % tolerance, switched
    relays that the record's grid clips away; they stayed on (a −90 nm offset) for the next 1,400
    samples, which the grid called trained states: 26× the noise. On the grid continued over the
    whole record those states are untrained, and what is scored fits within 2×."""
    spec = case_plan()[19]
    assert spec.category == "null"
    case = make_case(spec, np.random.default_rng([20003, 19]))
    assert case["plant"] == "afmsim_preisach"
    rep = diagnose_record(load_record(case["columns"]), candidates=[])[0]
    assert rep["baseline"]["heldout_scoring"] == "trained_states"
    assert rep["baseline"]["gap_to_noise"] <= 2.0


def test_the_fallback_scoring_stops_at_a_hold_just_above_the_training_range():
    """A null step record of afmsim's stage (open-world seed 22001, case 18, spent): the training
    part determines the relay state of 1 held-out sample of 3,157, so the fallback scores the
    samples before the first excursion. A hold 0.08 V above the training part's highest (0.9 % of
    the range, inside the tolerance) missed the stage by 640 nm where the grid is clipped, and was
    counted: 36× the noise. The fallback now ends at any move beyond the range. (Split at 60 % as
    given: chosen, the split holds out an interior block in trained states instead.)"""
    spec = case_plan()[18]
    assert spec.category == "null"
    case = make_case(spec, np.random.default_rng([22001, 18]))
    assert case["plant"] == "afmsim_preisach"
    rep, _, internals = diagnose_record(load_record(case["columns"]), candidates=[], train_fraction=0.6)
    d = internals["design"]
    scored, rule = d.scored()
    assert rule == "before_excursion" == rep["baseline"]["heldout_scoring"]
    top = float(d.v_max[d.train].max())
    assert not (scored & (np.cumsum(d.v_max > top) > 0)).any()
    assert (~d.train & (d.v_max > top) & d.in_range).any()  # the hold is inside the tolerance
    assert rep["baseline"]["gap_to_noise"] < 10.0


def test_a_coupling_on_afmsims_stage_is_named_when_the_held_out_part_stays_in_trained_states():
    """A 1 % coupling on afmsim's stage under steps (open-world seed 19002, case 10, spent): a
    held-out step 0.06 V above the training range, scored as a trained state with clipped relays,
    missed the stage by 446 nm and left 195× the noise with nothing named (104× without the
    coupling); with the strict range the coupling is named first."""
    spec = case_plan()[10]
    assert spec.category == "effect" and [name for name, _ in spec.effects] == ["cross_coupling"]
    case = make_case(spec, np.random.default_rng([19002, 10]))
    assert case["plant"] == "afmsim_preisach"
    rep = diagnose_record(load_record(case["columns"]))[0]
    assert rep["verdict"][:1] == ["cross_coupling"]
    assert rep["baseline"]["gap_to_noise"] < 100.0
    assert rep["final"]["gap_to_noise"] < 0.2 * rep["baseline"]["gap_to_noise"]


@pytest.mark.parametrize("n_levels", [None, 24])
def test_every_candidate_fit_shares_the_grid(n_levels):
    t, v, train = _drive(4)
    rng = np.random.default_rng(5)
    x = _record(np.cumsum(np.abs(np.diff(v, prepend=v[0]))) % 3.0, v, rng)
    d = Design(t, v, x, None, train, n_levels=n_levels)
    base = fit_model(d, ModelSpec())
    drift = fit_model(d, ModelSpec(effects=("drift",)))
    width = d.n_levels + 1
    assert base.n_params == 2 + width * (width + 1) // 2 and drift.n_params == base.n_params + 2


def test_block_averaged_relay_features_are_the_block_means_of_the_full_rate_ones():
    v = excitation("noise", 1000.0, 3.0, np.random.default_rng(4))[1]
    fine = relay_features(v, 0.0, 10.0, 8)
    blocks = relay_features(v, 0.0, 10.0, 8, block=3)
    m = v.size // 3
    assert blocks.shape == (m, fine.shape[1])
    assert np.allclose(blocks, fine[: 3 * m].reshape(m, 3, -1).mean(axis=1))


def test_relay_features_follow_each_smoothed_relay_through_the_record():
    """The compiled kernel (sample by sample, every relay in turn) against the relay equation walked
    relay by relay in plain Python: s ← min(max(s, r(u − i)), r(u − j)), r the unit ramp, starting
    from r(u₀ − i); the same values to the last bit, in the order (i, j ≤ i) row by row."""
    v = excitation("noise", 1000.0, 0.4, np.random.default_rng(7))[1]
    n, lo, hi = 6, float(v.min()), float(v.max())
    u = (v - lo) / (hi - lo) * n

    def ramp(z):
        return min(max(z, 0.0), 1.0)

    expected = []
    for i in range(n):
        for j in range(i + 1):
            s, states = ramp(u[0] - i), []
            for z in u:
                s = min(max(s, ramp(z - i)), ramp(z - j))
                states.append(s)
            expected.append(states)
    assert np.array_equal(relay_features(v, lo, hi, n), np.array(expected).T)


def test_a_decimated_record_is_fitted_with_full_rate_hysteresis():
    """5 Hz triangles sampled at 500 Hz for 40 s are block-mean decimated 3×: the averaged voltage
    misses every turning point's peak by up to a third of a sample's travel. Relays switched by the
    full-rate voltage and then averaged, as the record's x was, fit it to the noise."""
    rng = np.random.default_rng(7)
    fs, m = 500.0, 100
    v = np.concatenate([rng.uniform(3.0, 9.5) * (1.0 - np.abs(1.0 - 2.0 * np.arange(m) / m)) for _ in range(200)])
    t = np.arange(v.size) / fs
    rec = load_record({"t_s": t, "v_V": v, "x_m": AsymmetricPreisach().apply(v) + 5e-9 * rng.standard_normal(v.size)})
    assert rec.decimation == 3 and rec.v_fine.size == 3 * rec.n
    sigma = 5e-9 / np.sqrt(rec.decimation)  # block means of white noise
    train = np.arange(rec.n) < int(0.6 * rec.n)
    gaps = {}
    for label, v_fine in (("full rate", rec.v_fine), ("averaged drive", None)):
        d = Design(rec.t, rec.v, rec.x, None, train, v_fine=v_fine)
        held, _ = d.scored()
        gaps[label] = float(np.sqrt(np.mean((rec.x - fit_model(d, ModelSpec(kind=d.family)).prediction)[held] ** 2))) / sigma
    assert gaps["full rate"] < 2.0 < 10.0 < gaps["averaged drive"], gaps


@pytest.mark.parametrize("seed", [100, 101])
def test_a_duhem_class_stage_gets_the_bouc_wen_baseline_and_a_relay_stage_the_grid(seed):
    """Generalised cross-validation on the training part picks the family: Bouc–Wen for a Bouc–Wen plant
    (no return-point memory: no relay density fits it), the grid for afmsim's Preisach stage and
    for a generalised Prandtl–Ishlinskii one; on the Bouc–Wen record the held-out gap is then
    within 2× the noise (development seeds 100–101)."""
    rng = np.random.default_rng(seed)
    t, v = excitation("sines", 1000.0, 12.0, rng)
    plants = {"bouc_wen": null_plant("bouc_wen", v, rng), "afmsim": AsymmetricPreisach().apply(v),
              "generalised_pi": null_plant("generalised_pi", v, rng)}
    for name, x in plants.items():
        x = x + 8e-9 * rng.standard_normal(v.size)
        rep = diagnose_record(load_record({"t_s": t, "v_V": v, "x_m": x}), candidates=[])[0]
        assert rep["baseline"]["family"] == ("bouc_wen" if name == "bouc_wen" else "preisach"), name
        if name == "bouc_wen":
            assert rep["baseline"]["gap_to_noise"] <= 2.0 and rep["status"] == "nothing_missing"
            assert rep["baseline"]["bouc_wen_shape"]["beta"] > abs(rep["baseline"]["bouc_wen_shape"]["gamma"])


def test_the_bouc_wen_state_integrates_a_drive_term_that_changes_along_the_voltage():
    """The law's state against an independent integration (scipy's adaptive Runge–Kutta, one
    monotone segment at a time) of dh/du = A(u) − (β·sign(du·h) + γ)·|h|ⁿ with A linear in u
    (``a_low`` at u = 0, ``a_high`` at u = 1; the Coleman–Hodgdon class when n = 1, γ = 0)."""
    from scipy.integrate import solve_ivp

    from afmsim.diagnosis.loops.bouc_wen import BoucWenShape, bouc_wen_state

    shape = BoucWenShape(beta=6.0, gamma=1.5, n=1.4, a_low=0.3, a_high=1.6)
    vertices = [0.0, 1.0, 0.25, 0.8]
    u = np.concatenate([np.linspace(a, b, 200, endpoint=False) for a, b in zip(vertices[:-1], vertices[1:])] + [[0.8]])
    h, expected = 0.0, [0.0]
    for a, b in zip(vertices[:-1], vertices[1:]):
        direction = np.sign(b - a)

        def law(_, state, direction=direction):
            drive = shape.a_low + (shape.a_high - shape.a_low) * _
            return [drive - (shape.beta * np.sign(direction * state[0]) + shape.gamma) * abs(state[0]) ** shape.n]

        grid = np.linspace(a, b, 201)
        sol = solve_ivp(law, (a, b), [h], t_eval=grid, rtol=1e-10, atol=1e-12, max_step=1e-3)
        expected += list(sol.y[0, 1:])
        h = sol.y[0, -1]
    got = bouc_wen_state(u, shape)
    assert np.max(np.abs(got - np.array(expected))) < 1e-3 * np.ptp(expected)
    constant = bouc_wen_state(u, BoucWenShape(beta=6.0, gamma=1.5, n=1.4))  # A ≡ 1: the classic law
    assert np.max(np.abs(constant - got)) > 0.1 * np.ptp(expected)


def test_the_dahl_law_state_matches_the_dahl_plant_integrated_on_its_own():
    """The family's Dahl law on the normalised voltage against the null plant's own explicit
    integration of dF/dv = σ·|z|^α·sign(z), z = 1 − sign(dv)·F/F_c (:func:`null_plants._dahl`,
    other code): with u = v/R, F = σR·h and β = σR/F_c (A ≡ 1), for α below, at and above 1."""
    from afmsim.diagnosis.loops.bouc_wen import BoucWenShape, bouc_wen_state
    from afmsim.diagnosis.loops.null_plants import _dahl

    _, v = excitation("noise", 1000.0, 3.0, np.random.default_rng(310))
    r = 10.0
    for sigma, fc, alpha in ((3.0, 1.2, 0.6), (2.0, 0.8, 1.0), (4.0, 1.5, 1.8)):
        plant = _dahl(v, sigma, fc, alpha, 1e-4)
        law = sigma * r * bouc_wen_state(v / r, BoucWenShape(beta=sigma * r / fc, gamma=0.0, n=1.0, law="dahl", alpha=alpha))
        assert np.max(np.abs(law - plant)) < 5e-4 * np.ptp(plant), (alpha, np.max(np.abs(law - plant)) / np.ptp(plant))


@pytest.mark.parametrize("seed", [311, 312])
def test_a_dahl_stage_gets_the_dahl_law_and_no_bouc_wen_law_fits_it(seed):
    """A Dahl stage whose approach exponent is not 1 (Duhem class, no Bouc–Wen law): the family's
    shape search keeps the Dahl law and fits the training part close to the noise, where the
    Bouc–Wen law alone leaves more than twice as much (the probe that prompted the law, seed 901:
    3.2–12× the noise held out before, 1.0–1.1× after; here development seeds 311–312)."""
    from afmsim.diagnosis.loops import bouc_wen
    from afmsim.diagnosis.loops.null_plants import dahl

    rng = np.random.default_rng(seed)
    _, v = excitation("triangles", 1000.0, 6.0, rng)
    plant_seed = next(k for k in range(100) if abs(np.random.default_rng([seed, k]).uniform(0.5, 2.0) - 1.0) > 0.3)
    x = dahl(v, np.random.default_rng([seed, plant_seed])) + 8e-9 * rng.standard_normal(v.size)  # α: its first draw
    u = (v - v.min()) / np.ptp(v)
    free = np.column_stack([np.ones_like(u), u - 0.5])
    train = np.arange(v.size) < 0.6 * v.size
    shape, rms = bouc_wen.fit_bouc_wen_shape(u, 1, free, x, train)
    _, bw_rms = bouc_wen.fit_bouc_wen_shape(u, 1, free, x, train, laws=("bouc_wen",))
    assert shape.law == "dahl" and rms < 1.5 * 8e-9 < 2.0 * 8e-9 < bw_rms, (shape, rms, bw_rms)


@pytest.mark.parametrize("seed", [320, 322])
def test_a_decimated_step_record_of_a_duhem_stage_with_a_curved_backbone_is_fitted(seed):
    """The Bouc–Wen family's backbone u'², u'³ is the block mean of the full-rate voltage's powers,
    as the decimated record's x is: a Coleman–Hodgdon stage (its anhysteretic curve curved) under
    7–9 V steps at 200 Hz, block-mean decimated 2×, is fitted within 1.5× the noise on its training
    part and 2× held out; squaring the block-mean voltage left 1.9× (grid taken, 2.6× on training)
    and 36× on these development seeds."""
    rng = np.random.default_rng(seed)
    t, v = excitation("steps", 200.0, 60.0, rng)
    x = null_plant("coleman_hodgdon", v, rng) + 8e-9 * rng.standard_normal(v.size)
    rec = load_record({"t_s": t, "v_V": v, "x_m": x})
    assert rec.decimation == 2 and np.max(np.abs(np.diff(v))) > 7.0
    base = diagnose_record(rec, candidates=[])[0]["baseline"]
    assert base["family"] == "bouc_wen"
    assert base["gap_to_noise"] <= 2.0 and base["train_rms"] <= 1.5 * base["noise_floor"], base["gap_to_noise"]


@pytest.mark.parametrize("family", ["bouc_wen", "coleman_hodgdon"])
def test_freeing_the_drive_term_never_fits_the_training_part_worse_than_the_classic_law(family, monkeypatch):
    """The Bouc–Wen law's search frees the drive term only from the classic law's optimum, so its
    training error is never above the classic law's (a joint search from a grid of starts once lost
    that optimum); on a Coleman–Hodgdon stage it is far below. (The Bouc–Wen law alone: the Dahl
    law's search frees its drive term too.)"""
    from afmsim.diagnosis.loops import bouc_wen

    rng = np.random.default_rng(302)
    _, v = excitation("sines", 1000.0, 4.0, rng)
    x = null_plant(family, v, rng) + 8e-9 * rng.standard_normal(v.size)
    u = (v - v.min()) / np.ptp(v)
    free = np.column_stack([np.ones_like(u), u - 0.5])
    train = np.arange(v.size) < 0.6 * v.size
    shape, rms = bouc_wen.fit_bouc_wen_shape(u, 1, free, x, train, laws=("bouc_wen",))
    monkeypatch.setattr(bouc_wen, "DRIVE_TERM_EVALUATIONS", 0)
    classic, classic_rms = bouc_wen.fit_bouc_wen_shape(u, 1, free, x, train, laws=("bouc_wen",))
    assert (classic.a_low, classic.a_high) == (1.0, 1.0)
    assert rms <= classic_rms
    if family == "coleman_hodgdon":
        assert rms < 0.2 * classic_rms and abs(shape.a_high - shape.a_low) > 0.1


@pytest.mark.parametrize("kind", ["sines", "noise"])
def test_a_coleman_hodgdon_stage_gets_the_bouc_wen_family_with_its_changing_drive_term(kind, monkeypatch):
    """A Duhem stage whose drive term f′ − g changes along the voltage (:func:`coleman_hodgdon`) is
    fitted by the Bouc–Wen family once the law's drive term may change linearly too; with the
    classic law (constant drive term, the shape search of the earlier version) no family fits it
    within 2× the noise: 4 of the 12 development records that prompted the change (seeds
    [91, 0…11], the open-world suite's drives) within 2×, up to 135×; after it 23 of 24 on
    [91, 0…23] (also development: two of 12…23 prompted the linear-case start of the search), the
    one left a step record scored in untrained states (5.8×). Here development seeds 300 (sines)
    and 301 (noise)."""
    from afmsim.diagnosis.loops import bouc_wen

    rng = np.random.default_rng(300 if kind == "sines" else 301)
    t, v = excitation(kind, 1000.0, 12.0, rng)
    x = null_plant("coleman_hodgdon", v, rng) + 8e-9 * rng.standard_normal(v.size)
    columns = {"t_s": t, "v_V": v, "x_m": x}
    rep = diagnose_record(load_record(columns), candidates=[])[0]
    assert rep["baseline"]["family"] == "bouc_wen"
    assert rep["baseline"]["gap_to_noise"] <= 2.0 and rep["status"] == "nothing_missing"
    shape = rep["baseline"]["bouc_wen_shape"]
    assert abs(shape["a_high"] - shape["a_low"]) > 0.1
    monkeypatch.setattr(bouc_wen, "DRIVE_TERM_EVALUATIONS", 0)
    classic = diagnose_record(load_record(columns), candidates=[])[0]
    assert classic["baseline"]["gap_to_noise"] > 2.0, classic["baseline"]["gap_to_noise"]


def _prandtl_ishlinskii_stage(v, rng):
    """An asymmetric Prandtl–Ishlinskii stage (the paper's model class): 10 play operators of
    power-law half-widths up to 9 V with exponentially falling weights, a linear and a cubic
    reversible part, started at rest (every operator's output 0); 100 µm travel."""
    from afmsim.hysteresis import play

    widths = 10.0 * (np.arange(10) / 10.0) ** rng.uniform(1.0, 2.0)
    weights = np.exp(-rng.uniform(0.2, 0.6) * np.arange(10)) * rng.uniform(0.5, 1.5, 10)
    x = 0.4 * v + play(v, widths) @ weights + rng.uniform(-0.03, 0.03) * v**2 + rng.uniform(-0.002, 0.002) * v**3
    return (x - x[0]) / np.ptp(x) * 100e-6


@pytest.mark.parametrize("seed", [200, 201])
def test_a_prandtl_ishlinskii_stage_gets_the_fine_play_family(seed):
    """The relay grid puts a PI stage's operator kinks at its cell edges and misses it held out;
    generalised cross-validation on the training part picks the fine-play family, which misses it less (seeds 200–201, never used before
    this test; held-out gap 2.6× against the 32-level grid's 13.9×, and 3.3× against 5.0×, on the
    fine grid alone; 1.1× and 1.4× with its thresholds refined, :meth:`Design.refined_plays`)."""
    rng = np.random.default_rng(seed)
    t, v = excitation("noise", 1000.0, 12.0, rng)
    x = _prandtl_ishlinskii_stage(v, rng) + 8e-9 * rng.standard_normal(v.size)
    record = load_record({"t_s": t, "v_V": v, "x_m": x})
    rep = diagnose_record(record, candidates=[])[0]
    assert rep["baseline"]["family"] == "play"
    train = np.arange(record.n) < int(round(0.6 * record.n))
    design = Design(record.t, record.v, record.x, None, train, family="preisach")
    held, _ = design.scored()
    grid = fit_model(design, ModelSpec(kind="preisach"))
    grid_gap = np.sqrt(np.mean((grid.prediction - record.x)[held] ** 2)) / rep["baseline"]["noise_floor"]
    assert rep["baseline"]["gap_to_noise"] < grid_gap, (rep["baseline"]["gap_to_noise"], grid_gap)
    assert rep["baseline"]["gap_to_noise"] <= 2.0, rep["baseline"]["gap_to_noise"]


def test_the_play_family_refines_its_thresholds_towards_an_operator_between_grid_widths():
    """A stage of one sharp play operator whose half-width lies 0.37 of the way between two of the
    fine grid's: the grid's nearest play misses it by a third of the spacing (in units of the
    training range); the refined columns hold one within 1/64 of the spacing, and the baseline
    then fits the training part to the noise."""
    from afmsim.diagnosis.loops.model import N_FINE_PLAY, PLAY_REFINE, PLAY_REFINE_ROUNDS, fine_play_features
    from afmsim.hysteresis import play

    rng = np.random.default_rng(7)
    t, v, train = _drive(3)
    lo, hi = float(v[train].min()), float(v[train].max())
    radius = (30 + 0.37) / N_FINE_PLAY
    u = (np.clip(v, lo, hi) - lo) / (hi - lo)
    target = play(u, np.array([radius]), h0=u[0])[:, 0]
    x = 1e-5 * v + 2e-6 * target + 5e-9 * rng.standard_normal(v.size)
    design = Design(t, v, x, None, train, family="play")
    poly, fine = fine_play_features(design.vc, design.v_lo, design.v_hi, block=design.block)
    refined = design.hyst("play")[:, 2:]
    assert design.polarity == 1.0
    miss = lambda cols: np.abs(cols - target[:, None]).max(axis=0).min()  # noqa: E731
    spacing = 1.0 / N_FINE_PLAY
    assert miss(fine) > 0.3 * spacing
    assert refined.shape[1] > fine.shape[1]
    assert miss(refined) <= spacing / PLAY_REFINE**PLAY_REFINE_ROUNDS + 1e-3 * spacing
    fitted = fit_model(design, ModelSpec(kind="play"))
    sigma = noise_floor((fitted.prediction - x)[train])
    assert np.sqrt(np.mean((fitted.prediction - x)[train] ** 2)) < 1.2 * sigma


@pytest.mark.parametrize("seed", [100, 101])
def test_the_noise_floor_comes_from_where_the_drive_moves_least(seed):
    """A Preisach plant of 20 000 sharp relays (jumps of nanometres, coarser than the scattered null
    plant's default) under sine trains (40 s at 1 kHz, decimated 5×): every sample of a moving drive
    switches relays, and their jumps count as noise in second differences over all samples (2.6–2.7×
    the true σ); over the quietest tenth of the training samples the floor comes within 1.25×
    (development seeds 100–101)."""
    rng = np.random.default_rng(seed)
    t, v = excitation("sines", 1000.0, 40.0, rng)
    rec = load_record({"t_s": t, "v_V": v,
                       "x_m": scattered_preisach(v, rng, n_relays=20_000) + 8e-9 * rng.standard_normal(v.size)})
    train = np.arange(rec.n) < int(0.6 * rec.n)
    d = Design(rec.t, rec.v, rec.x, None, train, v_fine=rec.v_fine)
    residual = rec.x - fit_model(d, ModelSpec(kind=d.family)).prediction
    true = 8e-9 / np.sqrt(rec.decimation)
    assert noise_floor(residual[train]) > 2.0 * true
    assert 0.8 * true < d.noise_floor(residual) < 1.25 * true


def test_a_bouc_wen_stage_under_steps_gets_the_law_where_an_inner_split_tied():
    """A Bouc–Wen stage under steps (open-world development seed 1, case 25): on an inner split of
    the training part the grid and the law tied, and the grid, taken then, left 55× the noise on the
    held-out part; generalised cross-validation on the whole training part takes the law (a dozen
    parameters against the grid's hundreds), within 2×."""
    spec = case_plan()[25]
    assert spec.category == "null" and spec.plant == "bouc_wen"
    case = make_case(spec, np.random.default_rng([1, 25]))
    rep = diagnose_record(load_record(case["columns"]), candidates=[])[0]
    assert rep["baseline"]["family"] == "bouc_wen"
    assert rep["baseline"]["gap_to_noise"] <= 2.0


def test_a_drift_in_the_record_does_not_hide_which_family_the_stage_is():
    """A Bouc–Wen stage with a 90 nm/min warm-up drift under steps (open-world development seed 2,
    case 3): without the drift among the family check's free columns the grid was taken and the
    drift could not be named (33× the noise held out); with it, the law is taken (4.5×), the drift
    is named and takes the rest to within 2× the noise (its training-part rate, 104 nm/min, is
    just above the plausible bound: a warm-up is steepest early)."""
    spec = case_plan()[3]
    assert spec.category == "effect" and [name for name, _ in spec.effects] == ["drift"]
    case = make_case(spec, np.random.default_rng([2, 3]))
    assert case["plant"] == "bouc_wen"
    rep = diagnose_record(load_record(case["columns"]))[0]
    assert rep["baseline"]["family"] == "bouc_wen"
    assert rep["verdict"][:1] == ["drift"]
    assert rep["baseline"]["gap_to_noise"] < 10.0
    assert rep["final"]["gap_to_noise"] <= 2.0


@pytest.mark.parametrize("seed_case, family", [((18001, 5), "preisach"), ((18001, 6), "bouc_wen")])
def test_a_creep_in_the_record_does_not_pick_the_family_that_absorbs_it(seed_case, family):
    """Creep of 1.5 %/decade on afmsim's stage and of 2 %/decade on a Bouc–Wen stage, both under
    triangles (open-world seeds 18001, cases 5 and 6, spent): with only a drift and the cross axis
    among the family check's free columns, the play family (case 5) and the grid (case 6) fitted
    the creep into their loops on the inner part and were taken; nothing was named and 42× the
    noise was left on both. With the drive's relaxation bank among those columns the stage's own
    family is taken (the one a record without the creep gets) and creep is named first."""
    seed, index = seed_case
    spec = case_plan()[index]
    assert spec.category == "effect" and [name for name, _ in spec.effects] == ["creep"]
    case = make_case(spec, np.random.default_rng([seed, index]))
    rep = diagnose_record(load_record(case["columns"]))[0]
    assert rep["baseline"]["family"] == family
    assert rep["verdict"][:1] == ["creep"]
    assert rep["final"]["gap_to_noise"] < 0.5 * rep["baseline"]["gap_to_noise"]


def test_with_effects_the_bouc_wen_shape_is_refitted_jointly_with_them():
    """A 2.8 %/decade creep on a Bouc–Wen stage under steps (open-world development seed 1, case 7),
    fitted with the law: the baseline's shape, fitted with the creep still in the record, absorbs
    part of it (the creep fit on it shrinks the held-out gap by 53 %, two relaxations per decade);
    refitted jointly with the creep bank, by 98 % (one per decade: 25 % and 87 %)."""
    spec = case_plan()[7]
    assert spec.category == "effect" and [name for name, _ in spec.effects] == ["creep"]
    case = make_case(spec, np.random.default_rng([1, 7]))
    assert case["plant"] == "bouc_wen"
    rec = load_record(case["columns"])
    train = np.arange(rec.n) < int(0.6 * rec.n)
    d = Design(rec.t, rec.v, rec.x, None, train, v_fine=rec.v_fine, family="bouc_wen")
    held, _ = d.scored()
    creep = ModelSpec(kind="bouc_wen", effects=("creep",))

    def gap(fitted):
        return float(np.sqrt(np.mean((fitted.prediction - d.x)[held] ** 2)))

    baseline = gap(fit_model(d, ModelSpec(kind="bouc_wen")))
    with_baseline_shape = gap(_fit_columns(d, creep, d.hyst("bouc_wen"))[0])
    joint = gap(fit_model(d, creep))
    assert with_baseline_shape > 0.4 * baseline
    assert joint < 0.2 * with_baseline_shape


def test_a_gap_scored_in_untrained_relay_states_says_so():
    """A generalised-PI null under band-limited noise (open-world seed 14002, case 23, published),
    split at 60 % as given (no later split holds out trained states: at 80 %, the first with any, 3 %
    of the held-out part would be scored; :func:`choose_split` holds out an interior block instead):
    the training part reaches its top voltage only in its last samples, so no held-out sample is in a
    relay state it determines (0 of 3200; a fit on the whole record leaves 8×); the gap scored by the
    fallback rule (91× the noise) is the grid's extrapolation, and the summary says so. A record whose
    held-out states are trained gets no such line."""
    spec = case_plan()[23]
    assert spec.category == "null"
    case = make_case(spec, np.random.default_rng([14002, 23]))
    rep, summary, _ = diagnose_record(load_record(case["columns"]), candidates=[], train_fraction=0.6)
    assert rep["baseline"]["heldout_scoring"] == "before_excursion" and rep["record"]["split"] == "given"
    assert choose_split(load_record(case["columns"]))[1] == "interior_block"  # chosen, it holds out trained states
    assert rep["status"] == "unexplained"
    assert "relay states that the training part determines" in summary
    t, v, train = _drive()
    x = _record(AsymmetricPreisach().apply(np.clip(v, 0.0, 10.0)), v, np.random.default_rng(1))
    rep, summary, _ = diagnose_record(load_record({"t_s": t, "v_V": v, "x_m": x}), candidates=[])
    assert rep["baseline"]["heldout_scoring"] == "trained_states"
    assert "relay states that the training part determines" not in summary


@pytest.mark.parametrize("seed", [100, 103])
def test_the_gcv_weakens_the_density_prior_for_a_sharp_density_only(seed):
    """A generalised Prandtl–Ishlinskii stage (no operator narrower than a minimum threshold: a
    density with a sharp edge) under triangles: generalised cross-validation on the training part
    takes the weaker prior of SMOOTHING_CHOICES, and the held-out gap is then at least 20 % smaller
    than with the default prior on the same grid; afmsim's own stage (a smooth density) keeps the
    default (development seeds 100–107: the sharp density took the weaker prior on all 8 records,
    its gap 26–49 % smaller on every one; afmsim's stage on none)."""
    rng = np.random.default_rng(seed)
    t, v = excitation("triangles", 1000.0, 12.0, rng)
    plants = {"generalised_pi": null_plant("generalised_pi", v, rng), "afmsim": AsymmetricPreisach().apply(v)}
    for name, x in plants.items():
        rec = load_record({"t_s": t, "v_V": v, "x_m": x + 8e-9 * rng.standard_normal(v.size)})
        train = np.arange(rec.n) < int(round(0.6 * rec.n))
        chosen = Design(rec.t, rec.v, rec.x, None, train, v_fine=rec.v_fine)
        if name == "afmsim":
            assert chosen.smoothing == SMOOTHING_CHOICES[0]
            continue
        assert chosen.family == "preisach" and chosen.smoothing == SMOOTHING_CHOICES[-1] < SMOOTHING_CHOICES[0]
        stiff = Design(rec.t, rec.v, rec.x, None, train, v_fine=rec.v_fine, n_levels=chosen.n_levels)
        assert stiff.smoothing == SMOOTHING_CHOICES[0]
        held, _ = chosen.scored()
        gap = {label: float(np.sqrt(np.mean((rec.x - fit_model(d, ModelSpec(kind="preisach")).prediction)[held] ** 2)))
               for label, d in (("chosen", chosen), ("stiff", stiff))}
        assert gap["chosen"] < 0.8 * gap["stiff"], gap


def test_a_sensor_mounted_the_other_way_round_gets_the_same_diagnosis():
    """x falling with the drive (the sensor's sign flipped) is the same stage: the relay density
    stays ≥ 0 with negated columns, so the held-out gap and the noise floor do not change."""
    t, v, _ = _drive(4)
    rng = np.random.default_rng(5)
    x = null_plant("generalised_pi", v, rng, travel_m=20e-6) + 5e-9 * rng.standard_normal(v.size)
    upright, _, _ = diagnose_record(load_record((t, v, x)), candidates=[])
    flipped, summary, _ = diagnose_record(load_record((t, v, -x)), candidates=[])
    assert upright["baseline"]["drive_polarity"] == 1 and flipped["baseline"]["drive_polarity"] == -1
    assert flipped["baseline"]["family"] == upright["baseline"]["family"]
    assert flipped["baseline"]["rms_gap"] == pytest.approx(upright["baseline"]["rms_gap"], rel=1e-6)
    assert flipped["baseline"]["noise_floor"] == pytest.approx(upright["baseline"]["noise_floor"], rel=1e-6)
    assert "Polarity" in summary


def _peak_at_the_split():
    """Triangles whose highest peak (8.7 V) the first 60 % of the time rises to but never leaves:
    every later descent starts from a relay state no earlier sample had."""
    knots_t = [0, 0.3, 1.3, 2.3, 3.3, 4.3, 4.8, 5.3, 6.3, 7.3, 7.4, 7.5, 7.7, 8.0, 8.2]
    knots_v = [0, 0, 6.9, 0, 5.6, 0, 8.7, 0, 4.0, 0, 7.4, 0, 6.2, 0, 2.1]
    t = np.arange(0.0, 8.2, 1e-3)
    return t, np.interp(t, knots_t, knots_v)


def test_the_split_moves_on_until_the_held_out_states_are_trained():
    """afmsim's own stage, no effect: split at 60 %, the held-out part descends from a peak the
    training part only rose to, and the grid's extrapolation to those relay states leaves 15× the
    noise (fallback scoring); the chosen split (70 %) holds out states the training part determines
    (for at least a quarter of its samples, MIN_MOVED_SHARE), and the same record is
    nothing_missing. The choice looks at the drive only: a
    displacement that is pure noise gets the same split."""
    t, v = _peak_at_the_split()
    x = AsymmetricPreisach().apply(v) + 8e-9 * np.random.default_rng(3).standard_normal(t.size)
    rec = load_record({"t_s": t, "v_V": v, "x_m": x})
    train, rule = choose_split(rec)
    assert rule == "moved_to_trained_states" and train.mean() == pytest.approx(0.7, abs=1e-3) and train[0]
    fixed, fixed_summary, _ = diagnose_record(rec, candidates=[], train_fraction=0.6)
    assert "Split:" not in fixed_summary
    chosen, summary, _ = diagnose_record(rec, candidates=[])
    assert "Split: the first 70 % of the record is fitted, not 60 %" in summary
    assert fixed["baseline"]["heldout_scoring"] == "before_excursion" and fixed["baseline"]["gap_to_noise"] > 5.0
    assert chosen["record"]["train_fraction"] == 0.7 and chosen["record"]["split"] == "moved_to_trained_states"
    assert chosen["baseline"]["heldout_scoring"] == "trained_states" and chosen["baseline"]["gap_to_noise"] < 2.0
    assert chosen["status"] == "nothing_missing"
    noise = load_record({"t_s": t, "v_V": v, "x_m": 8e-9 * np.random.default_rng(4).standard_normal(t.size)})
    same_train, same_rule = choose_split(noise)
    assert same_rule == rule and np.array_equal(same_train, train)
    t, v, _ = _drive()
    steady = load_record({"t_s": t, "v_V": v, "x_m": _record(AsymmetricPreisach().apply(v), v, np.random.default_rng(1))})
    train, rule = choose_split(steady)
    assert rule == "default" and train.mean() == pytest.approx(0.6, abs=1e-3)


def test_a_gap_the_prior_sets_is_read_as_prior_dependent():
    """afmsim's stage under band-limited noise, no effect (spent open-world seed 31002, case 19),
    split at 60 % as given: every held-out sample is in a relay state the training part does not
    determine, the baseline
    leaves 8.8× the noise held out, and the relay grid's two admissible priors predict the held-out
    part further apart than that gap's excess over the noise: the reading says the gap tests the
    prior. The same stage under triangles (31002/18, trained held-out states, 1.0×) has a spread
    below the noise and no such reading."""
    spec = case_plan()[19]
    assert spec.category == "null"
    case = make_case(spec, np.random.default_rng([31002, 19]))
    assert case["plant"] == "afmsim_preisach" and case["excitation"] == "noise"
    rep, summary, _ = diagnose_record(load_record(case["columns"]), candidates=[], train_fraction=0.6)
    b, un = rep["baseline"], rep["unexplained"]
    assert b["family"] == "preisach" and b["heldout_scoring"] == "before_excursion"
    assert rep["status"] == "unexplained" and b["gap_to_noise"] > 2.0
    assert b["prior_spread_to_noise"] ** 2 >= b["gap_to_noise"] ** 2 - 1.0
    assert b["prior_dependent_share"] > 0.5
    assert un["reading"] == "prior_dependent" and un["prior_spread_to_noise"] == b["prior_spread_to_noise"]
    assert "the gap tests the prior, not the data" in summary
    case = make_case(case_plan()[18], np.random.default_rng([31002, 18]))
    rep, summary, _ = diagnose_record(load_record(case["columns"]), candidates=[])
    assert rep["baseline"]["heldout_scoring"] == "trained_states"
    assert rep["baseline"]["prior_spread_to_noise"] < 1.0
    assert "reading" not in rep["unexplained"] and "tests the prior" not in summary


def test_an_interior_block_tests_the_baseline_where_no_split_at_the_end_can():
    """The same record as above (spent seed 31002, case 19), its split chosen: no split at the end
    holds out a part in relay states the training part determines, so a block inside the record is
    held out, the parts before and after it fitted — chosen from the drive alone (a displacement of
    pure noise gets the same block), its voltage inside the rest's range. The baseline then leaves
    less than 2× the noise held out, in trained states: ``nothing_missing`` where the end-split read
    8.8×. The summary names the held-out span."""
    case = make_case(case_plan()[19], np.random.default_rng([31002, 19]))
    rec = load_record(case["columns"])
    train, rule = choose_split(rec)
    assert rule == "interior_block" and train[0] and train[-1] and not train.all()
    block = np.flatnonzero(~train)
    assert np.all(np.diff(block) == 1) and block.size == pytest.approx(0.2 * rec.n, abs=1)
    assert rec.v[block].max() < rec.v[train].max() and rec.v[block].min() > rec.v[train].min()
    noise = load_record({"t_s": rec.t, "v_V": rec.v, "x_m": 8e-9 * np.random.default_rng(2).standard_normal(rec.n)})
    assert np.array_equal(choose_split(noise)[0], train)
    rep, summary, _ = diagnose_record(rec, candidates=[])
    r, b = rep["record"], rep["baseline"]
    assert r["split"] == "interior_block" and r["heldout_from_s"] == pytest.approx(rec.t[block[0]])
    assert r["heldout_to_s"] == pytest.approx(rec.t[block[-1]]) and b["heldout_scoring"] == "trained_states"
    assert b["gap_to_noise"] < 2.0 and rep["status"] == "nothing_missing"
    assert "is held out and the parts before and after it fitted" in summary


def test_a_tenth_long_block_tests_the_baseline_where_no_fifth_can(monkeypatch):
    """Spent fresh seed 37003, null 18 (afmsim's own stage under a step drive): no split at the
    end and no block a fifth of the record long holds out a part in trained relay states — with
    fifths only the split falls back (``default_untrained``; the benchmark read 18.5× there). A
    block a tenth long, with more of the drive's excursions left to train on, is scored in trained
    states, and the baseline fits it to within 2× of the noise: ``nothing_missing``."""
    from afmsim.diagnosis.loops import attribute

    case = make_case(case_plan()[18], np.random.default_rng([37003, 18]))
    assert case_plan()[18].category == "null" and case["excitation"] == "steps"
    rec = load_record(case["columns"])
    monkeypatch.setattr(attribute, "BLOCK_LENGTHS", (0.2,))
    assert choose_split(rec)[1] == "default_untrained"
    monkeypatch.undo()
    train, rule = choose_split(rec)
    block = np.flatnonzero(~train)
    assert rule == "interior_block" and np.all(np.diff(block) == 1)
    assert block.size == pytest.approx(0.1 * rec.n, abs=1) and train[0] and train[-1]
    rep, _, _ = diagnose_record(rec, candidates=[])
    assert rep["record"]["split"] == "interior_block" and rep["baseline"]["heldout_scoring"] == "trained_states"
    assert rep["baseline"]["gap_to_noise"] < 2.0 and rep["status"] == "nothing_missing"


def test_a_gap_held_out_where_no_split_trains_the_states_is_read_as_an_extrapolation(monkeypatch):
    """Spent fresh seed 35003, null 18: afmsim's own stage under a 2.7 s noise drive, with no
    interior block to try (``BLOCK_STARTS`` emptied; with them, it gets one and fits to 1.05×). No
    split holds out a part in relay states the training part determines, so every held-out sample
    is scored; the baseline fits its training part to the noise and leaves 5.7× held out, more than
    the two priors' spread covers. The reading says the gap measures an extrapolation, and the
    verdict is unchanged (``unexplained``, nothing named)."""
    from afmsim.diagnosis.loops import attribute

    monkeypatch.setattr(attribute, "BLOCK_STARTS", ())
    case = make_case(case_plan()[18], np.random.default_rng([35003, 18]))
    assert case["plant"] == "afmsim_preisach" and case["excitation"] == "noise"
    rep, summary, _ = diagnose_record(load_record(case["columns"]), candidates=[])
    b, un = rep["baseline"], rep["unexplained"]
    assert rep["record"]["split"] == "default_untrained" and b["heldout_scoring"] == "before_excursion"
    assert rep["status"] == "unexplained" and b["gap_to_noise"] > 2.0 and un["train_gap_to_noise"] <= 2.0
    assert b["prior_spread_to_noise"] ** 2 < b["gap_to_noise"] ** 2 - 1.0  # not read as prior_dependent
    assert un["reading"] == "untrained_states" and "extrapolates into states it never saw" in summary


@pytest.mark.parametrize("reading, split, expected", [
    ("heldout_only", "default_untrained", "untrained_states"),
    ("heldout_only", "default", "heldout_only"),
    ("heldout_only", "moved_to_trained_states", "heldout_only"),
    ("prior_dependent", "default_untrained", "prior_dependent"),  # the spread's reading stays
    ("misfit_throughout", "default_untrained", "misfit_throughout"),
])
def test_only_a_held_out_only_remainder_of_a_fallen_back_split_is_read_as_untrained(reading, split, expected):
    from afmsim.diagnosis.loops.attribute import _read_untrained_split

    unexplained = {"reading": reading}
    _read_untrained_split(unexplained, split)
    assert unexplained["reading"] == expected


def test_the_two_priors_agree_on_the_training_part_they_both_fit():
    """The spread compares the grid's fits under SMOOTHING_CHOICES on the training part: on the
    training samples both fit the same data (5 nm noise), so they agree there to a fifth of the
    noise; it is a per-sample, non-negative array over the whole record."""
    t, v, train = _drive(3)
    rng = np.random.default_rng(4)
    x = _record(AsymmetricPreisach().apply(np.clip(v, 0.0, 10.0)), v, rng)
    d = Design(t, v, x, None, train)
    spread = d.prior_spread()
    assert spread.shape == t.shape and np.all(spread >= 0.0)
    assert set(d.grid_prior_fits) == set(SMOOTHING_CHOICES)
    assert np.sqrt(np.mean(spread[train] ** 2)) < 1e-9


@pytest.mark.parametrize("kind", ["triangles", "steps"])
def test_a_sensor_with_a_quadratic_calibration_error_is_still_a_rate_independent_null(kind):
    """afmsim's stage (100 µm travel) read through a sensor whose calibration bows by 0.5 % of the
    range at its ends (a parabola in x through both ends: 500 nm, 100× the 5 nm noise) is still a
    rate-independent hysteresis without an effect: the baseline comes within 2× the noise held out
    and names nothing. (A probe of a stage model outside the open-world plants; docs/diagnosis.md.)"""
    rng = np.random.default_rng(11)
    t, v = excitation(kind, 500.0, 12.0, rng)
    x = AsymmetricPreisach().apply(v)
    half = 0.5 * np.ptp(x)
    bow = 0.005 * np.ptp(x) * ((x - (x.min() + half)) / half) ** 2
    assert np.ptp(bow) > 100 * 5e-9
    rep, _, _ = diagnose_record(load_record({"t_s": t, "v_V": v, "x_m": x + bow + 5e-9 * rng.standard_normal(t.size)}))
    assert rep["baseline"]["gap_to_noise"] <= 2.0
    assert rep["status"] == "nothing_missing" and rep["verdict"] == []


def _spent_record(seed: int, index: int, plant: str, category: str | None = None):
    """The record of open-world case ``index`` of ``seed`` (spent), checked to be of ``plant`` (and ``category``)."""
    spec = case_plan()[index]
    assert category is None or spec.category == category
    case = make_case(spec, np.random.default_rng([seed, index]))
    assert case["plant"] == plant
    return load_record(case["columns"])


def test_the_first_samples_after_an_untrained_sine_peak_are_left_to_the_prior():
    """A null record of a generalised-PI stage under sines (open-world seed 60001, case 23, spent):
    the held-out part reverses at 4.6 V and 6.3 V, where no training sine peaked, and the first
    samples of each descent missed the stage by 30–75 nm (4 nm noise) in relay states 0.25–0.5
    relay units outside the trained directions — what the density prior set. Scored within
    STRICT_STATE_TOLERANCE the baseline fits within 2×, as a rate-independent stage must; scored
    within STATE_TOLERANCE it left 2.7×, and the samples between the two carry a residual several
    times that of the strict ones."""
    rep, _, internals = diagnose_record(_spent_record(60001, 23, "generalised_pi", "null"), candidates=[])
    d, held = internals["design"], internals["held"]
    assert rep["baseline"]["heldout_scoring"] == "trained_states"
    assert rep["baseline"]["heldout_state_tolerance"] == STRICT_STATE_TOLERANCE
    assert rep["baseline"]["gap_to_noise"] <= 2.0
    loose, rule = d.scored(strict=False)
    assert rule == "trained_states" and d.state_tolerance == STATE_TOLERANCE
    assert not (held & ~loose).any() and held.sum() > 0.8 * loose.sum()  # a subset, most of it
    r = d.x - internals["baseline"].prediction
    sigma = rep["baseline"]["noise_floor"]
    assert np.sqrt(np.mean(r[loose] ** 2)) / sigma > 2.0
    dropped = loose & ~held
    assert np.sqrt(np.mean(r[dropped] ** 2)) > 3 * np.sqrt(np.mean(r[held] ** 2))


@pytest.mark.parametrize("seed, index, plant, strict_at_most", [(60002, 20, "scattered_preisach", MIN_SCORED),
                                                                 (60001, 8, "scattered_preisach", None)])
def test_the_strict_state_tolerance_gives_way_where_it_leaves_too_few_samples(seed, index, plant, strict_at_most):
    """Band-limited-noise drives of a scattered-Preisach stage (open-world records, spent): on the
    null 60002/20, 181 held-out samples are trained states within STATE_TOLERANCE and 11 within
    STRICT_STATE_TOLERANCE, fewer than MIN_SCORED; on 60001/8 (a 0.1 % coupling) 287 and 50, less
    than STRICT_SHARE of them — scored so, the coupling's visible gap fell from 2.7× the noise to
    1.3×. The looser tolerance scores both."""
    rec = _spent_record(seed, index, plant)
    train, _ = choose_split(rec)
    d = Design(rec.t, rec.v, rec.x, rec.y, train, v_fine=rec.v_fine)
    strict, rule = d.scored()
    assert rule == "trained_states" and d.state_tolerance == STATE_TOLERANCE
    loose, _ = d.scored(strict=False)
    assert (strict == loose).all() and loose.sum() >= MIN_SCORED
    norm = untrained_state(d.relays_over_record(), d.train)
    within = np.count_nonzero(loose & (norm <= STRICT_STATE_TOLERANCE))
    assert 0 < within < max(MIN_SCORED, STRICT_SHARE * loose.sum())
    if strict_at_most is not None:
        assert within < strict_at_most
