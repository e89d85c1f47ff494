"""Sharp relays on a grid found in the record: a baseline family for discrete Preisach stages
(issue 11, point 3).

The textbook discrete Preisach model switches ideal relays at the nodes of a regular grid of the
voltage range. With a coarse grid (10–128 levels) every crossing of a grid voltage moves the stage
by (loop part)/N — 0.1–3 µm, a staircase — and the relay grid of :mod:`.model`, whose relays ramp
across their cells at the record's own levels, ramps where such a stage jumps: 3–74× the noise on
null records of such stages (docs/diagnosis.md, "Sharp relays on the record's own grid"). This
family finds the stage's grid and places sharp relays on it, from the training part only:

1. :func:`find_grid` — the spacing and phase of the grid, from a periodogram of the training part's
   sample-to-sample increments over the voltage: each increment signed by its direction, a smooth
   slope per direction removed (the reversible and the smooth hysteretic part), the jumps left as a
   comb whose spacing is the grid's. Increments over more than a quarter of a trial spacing are left
   out (they cannot place a jump). The first :data:`HARMONICS` harmonics are summed; the family is
   offered only where the peak stands :data:`MIN_COMB_RATIO` × above the periodogram's median, away
   from the ends of the trial spacings;
2. :func:`place_levels` — each threshold placed on its own: a regular grid found to 0.1 % of its
   spacing is still 0.01 V off at its far end, and under a slow drive that misassigns a sample or
   two at every crossing of a micrometre jump. Level by level, with the other weights held, the
   threshold moves to just above the training voltage (within a quarter spacing, between its
   neighbours) that minimises the training error — a drive written by a converter sits on the same
   voltages again and again, and which side of a threshold a sample lies on is what counts;
   :data:`PLACEMENT_SWEEPS` sweeps, the weights refitted after each; on grids finer than
   :data:`FREE_LEVELS` the density is bilinear on a coarse grid (:func:`density_map`) and the
   thresholds are placed without per-relay refits (:func:`place_at_jumps`, :func:`refine_fine_levels`);
3. :func:`sharp_columns` — relay (i, j ≤ i) on at or above level i, off below level j (ideal
   relays, from rest below the first sample), at the full rate and block-averaged as the record;
4. :func:`undetermined_samples` — a threshold anywhere between the training voltages just below and
   just above it fits the training part alike; a held-out voltage inside that interval (a
   periodic training drive visits the same voltages again and again, the held-out part others)
   switches a relay that the training part does not place. Such samples are not scored
   (:meth:`.model.Design.scored`).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.linalg import solve_triangular
from scipy.optimize import nnls

__all__ = ["find_grid", "grid_levels", "place_levels", "place_at_jumps", "sharp_columns", "relay_columns",
           "density_map", "density_size", "relay_pairs", "undetermined_samples", "tied_thresholds", "MIN_COMB_RATIO", "MAX_LEVELS",
           "FREE_LEVELS"]

#: Harmonics of the grid spacing summed in the periodogram of :func:`find_grid`.
HARMONICS = 3
#: The comb's peak over the periodogram's median at which the family is offered. On sharp-relay
#: grid stages (development seeds 901–907) the peak stood 5.7–70× above it where the drive moves in
#: small increments (sines, triangles, noise) and 1.3× under steps; on smooth stages of the spent
#: suite records up to 9.5× (fine spacings: kinks, leakage), where the family's start must then
#: beat the other families (:attr:`.model.Design.sharp_grid`).
MIN_COMB_RATIO = 5.0
#: A line at 1/(k·s) this strong against the one at 1/s makes the grid's spacing k·s (:func:`find_grid`).
SUBHARMONIC_SHARE = 0.5
#: Fewest and most grid levels over the training range that :func:`find_grid` tries. A stage of
#: 64 levels over 0–10 V (about 50 over a training range) was left at 9–13× the noise when the
#: most was 48 (development seed 906).
MIN_LEVELS, MAX_LEVELS = 6, 128
#: Up to this many levels each relay has its own weight (the relay count grows with the square: 48
#: levels are 1,176 relays, twice the 32-level grid's) and each threshold is placed with its relays'
#: weights refitted (:func:`place_levels`); on a finer grid the relays' density is bilinear on a
#: coarse grid of :data:`DENSITY_LEVELS` levels (:func:`density_map`), and the thresholds start from
#: the best of the grid as found, snapped and placed at the jumps (:func:`place_at_jumps`), then
#: move with the weights held (:func:`refine_fine_levels`; :attr:`.model.Design.sharp_grid`).
FREE_LEVELS = 48
DENSITY_LEVELS = 24
#: Training RSS within which another place of a threshold fits as well (:func:`tied_thresholds`), in
#: the fit's own residual variances (about the 95 % point of a χ² with one degree of freedom), and
#: the most training voltages it steps each way.
TIE_VARIANCES = 4.0
TIE_STEPS = 20
#: Training voltages nearest to each fine-grid threshold tried by :func:`refine_fine_levels`, and its sweeps.
FINE_CANDIDATES = 40
FINE_SWEEPS = 2
#: Trial spacings of the periodogram (log-spaced between the two level counts), and the share of
#: them at either end where a peak is not taken for a grid: on the spent open-world records of
#: 47001 the smooth stages' largest peak (7.5× the median, a Bouc–Wen stage under triangles) lay on
#: the coarsest spacing tried.
N_TRIAL_SPACINGS = 1000
EDGE_SHARE = 0.01
#: Sweeps of the threshold placement, and the most sample voltages tried per threshold and sweep.
PLACEMENT_SWEEPS = 3
MAX_CANDIDATES = 200
#: Evenly spaced training voltages per threshold and sweep tried with the level's weights refitted.
REFIT_CANDIDATES = 8
#: Legendre degree of the smooth slope removed from the increments, per direction.
SLOPE_DEGREE = 6


@njit(cache=True, nogil=True)
def _mapped_relays(v, up, down, columns, weights, n_columns, block):  # pragma: no cover - compiled
    """Block means of Σ_r weights[r, k]·state_r in column columns[r, k] (ideal relays, as below)."""
    m = v.size // block
    out = np.zeros((m, n_columns))
    state = np.zeros(up.size, dtype=np.bool_)
    for r in range(up.size):
        state[r] = v[0] >= up[r]
    w = 1.0 / block
    for t in range(m * block):
        row = out[t // block]
        for r in range(up.size):
            if v[t] >= up[r]:
                state[r] = True
            elif v[t] < down[r]:
                state[r] = False
            if state[r]:
                for k in range(columns.shape[1]):
                    row[columns[r, k]] += w * weights[r, k]
    return out


@njit(cache=True, nogil=True)
def _states_differ(v, up_a, down_a, up_b, down_b, block):  # pragma: no cover - compiled
    """Per block: whether any relay's state differs between thresholds (up_a, down_a) and (up_b, down_b)."""
    m = v.size // block
    out = np.zeros(m, dtype=np.bool_)
    a = np.zeros(up_a.size, dtype=np.bool_)
    b = np.zeros(up_a.size, dtype=np.bool_)
    for r in range(up_a.size):
        a[r] = v[0] >= up_a[r]
        b[r] = v[0] >= up_b[r]
    for t in range(m * block):
        differ = False
        for r in range(up_a.size):
            if v[t] >= up_a[r]:
                a[r] = True
            elif v[t] < down_a[r]:
                a[r] = False
            if v[t] >= up_b[r]:
                b[r] = True
            elif v[t] < down_b[r]:
                b[r] = False
            differ = differ or (a[r] != b[r])
        if differ:
            out[t // block] = True
    return out


def relay_pairs(n_levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Level indices (i, j ≤ i) of the relays, in the order of :func:`.model.relay_curvature`."""
    i, j = np.tril_indices(n_levels)
    order = np.lexsort((j, i))
    return i[order], j[order]


def sharp_columns(v_fine, levels, block: int = 1, pairs=None) -> np.ndarray:
    """Ideal relays (i, j ≤ i) on the voltage ``v_fine`` (V, full rate): on at or above
    ``levels[i]``, off below ``levels[j]``, from rest below the first sample; block means of
    ``block`` samples. ``pairs``: a subset of :func:`relay_pairs` (default: all)."""
    i, j = relay_pairs(len(levels)) if pairs is None else pairs
    levels = np.asarray(levels, dtype=np.float64)
    own = np.arange(i.size, dtype=np.int64)[:, None]  # each relay its own column
    return _mapped_relays(np.ascontiguousarray(v_fine, dtype=np.float64), levels[i], levels[j], own,
                          np.ones((i.size, 1)), i.size, int(block))


def density_map(n_levels: int, n_density: int = DENSITY_LEVELS) -> tuple[np.ndarray, np.ndarray]:
    """Each relay (i, j ≤ i) of an ``n_levels`` grid as bilinear weights on the four nearest nodes
    of an ``n_density`` grid of the density (nodes in the order of :func:`relay_pairs`; a neighbour
    above the diagonal, j > i, folds onto the diagonal node): ``(node indices, weights)``, both
    (relays × 4)."""
    i, j = relay_pairs(n_levels)
    scale = (n_density - 1) / max(n_levels - 1, 1)
    fi, fj = i * scale, j * scale
    i0 = np.minimum(np.floor(fi).astype(int), n_density - 2)
    j0 = np.minimum(np.floor(fj).astype(int), n_density - 2)
    di, dj = fi - i0, fj - j0

    def node(a, b):
        """Index of density node (a, min(b, a)) in the order of :func:`relay_pairs`."""
        return a * (a + 1) // 2 + np.minimum(b, a)

    columns = np.column_stack([node(i0, j0), node(i0 + 1, j0), node(i0, j0 + 1), node(i0 + 1, j0 + 1)])
    weights = np.column_stack([(1 - di) * (1 - dj), di * (1 - dj), (1 - di) * dj, di * dj])
    return columns.astype(np.int64), weights


def density_size(n_levels: int) -> int:
    """Levels of the grid whose density the relay weights are (:data:`FREE_LEVELS`, :func:`density_map`)."""
    return n_levels if n_levels <= FREE_LEVELS else DENSITY_LEVELS


def relay_columns(v_fine, levels, block: int = 1) -> np.ndarray:
    """The family's relay columns on ``levels``: one per relay (:func:`sharp_columns`) up to
    :data:`FREE_LEVELS` levels; on a finer grid one per node of the density's coarse grid, each the
    sum of the relays' states weighted by their bilinear share of that node (:func:`density_map`)."""
    levels = np.asarray(levels, dtype=np.float64)
    if levels.size <= FREE_LEVELS:
        return sharp_columns(v_fine, levels, block)
    i, j = relay_pairs(levels.size)
    columns, weights = density_map(levels.size)
    n = DENSITY_LEVELS * (DENSITY_LEVELS + 1) // 2
    return _mapped_relays(np.ascontiguousarray(v_fine, dtype=np.float64), levels[i], levels[j], columns, weights, n,
                          int(block))


def training_voltages(v_fine, train, block: int) -> np.ndarray:
    """The distinct full-rate voltages (V, sorted) of the training part's samples."""
    fine_train = np.repeat(np.asarray(train, bool), block)
    v_fine = np.asarray(v_fine, dtype=np.float64)[: fine_train.size]
    return np.unique(v_fine[fine_train[: v_fine.size]])


def snap_to_training(v_fine, train, block: int, levels) -> np.ndarray:
    """Each level (V) moved to just above its nearest training voltage (:func:`threshold_nudge`)."""
    v_train = training_voltages(v_fine, train, block)
    levels = np.asarray(levels, dtype=np.float64)
    nearest = np.clip(np.searchsorted(v_train, levels), 1, max(v_train.size - 1, 1))
    nearest -= (levels - v_train[nearest - 1]) < (v_train[nearest] - levels)
    return v_train[nearest] + threshold_nudge(v_fine)


def threshold_nudge(v_fine) -> float:
    """How far (V) above a sample voltage a threshold is placed: a billionth of the voltage range."""
    return 1e-9 * (float(np.ptp(v_fine)) or 1.0)


def undetermined_samples(v_fine, levels, train, block: int = 1, tied=None) -> np.ndarray:
    """Samples (of the block-mean record) whose relay states the training part does not determine.

    Each threshold may lie anywhere from just above the training voltage below it to the training
    voltage at or above it without changing a training state; the relays' states are monotone in
    their thresholds, so every placement's states lie between those of the two extreme placements
    (all thresholds at the low ends, all at the high ends). A sample where these differ depends on
    where in its interval a threshold lies — a held-out voltage between two training voltages, and
    the relay it switched, until its other threshold resets it. ``tied``: ``(lowest, highest)``
    thresholds (V, per level) that fit the training part as well within its noise
    (:func:`tied_thresholds`); the intervals then run from the lowest's to the highest's."""
    v_fine = np.asarray(v_fine, dtype=np.float64)
    levels = np.asarray(levels, dtype=np.float64)
    lowest, highest = (levels, levels) if tied is None else (np.asarray(tied[0], float), np.asarray(tied[1], float))
    v_train = training_voltages(v_fine, train, block)
    below = np.searchsorted(v_train, lowest, side="left")  # first training voltage ≥ the lowest
    above = np.searchsorted(v_train, highest, side="left")  # first training voltage ≥ the highest
    low = np.where(below > 0, v_train[np.maximum(below - 1, 0)] + threshold_nudge(v_fine), -np.inf)
    high = np.where(above < v_train.size, v_train[np.minimum(above, v_train.size - 1)], np.inf)
    low, high = np.minimum(low, levels), np.maximum(high, levels)
    low, high = np.where(np.isfinite(low), low, levels), np.where(np.isfinite(high), high, levels)
    i, j = relay_pairs(levels.size)
    return _states_differ(v_fine, low[i], low[j], high[i], high[j], int(block))


def _jump_increments(v, x, train):
    """Training increments: |Δv|, the direction-signed Δx less a smooth slope per direction, the
    voltage at the increment's middle, and its lower and upper end."""
    k = np.flatnonzero(train[:-1] & train[1:])
    dv = v[k + 1] - v[k]
    moves = dv != 0
    k, dv = k[moves], dv[moves]
    sign = np.sign(dv)
    dx = (x[k + 1] - x[k]) * sign
    mid = 0.5 * (v[k] + v[k + 1])
    jumps = np.empty_like(dx)
    span = float(np.ptp(mid)) or 1.0
    for direction in (-1.0, 1.0):
        m = sign == direction
        if m.sum() <= 2 * (SLOPE_DEGREE + 1):
            jumps[m] = dx[m]
            continue
        basis = np.abs(dv[m])[:, None] * np.polynomial.legendre.legvander(2.0 * (mid[m] - mid.min()) / span - 1.0, SLOPE_DEGREE)
        jumps[m] = dx[m] - basis @ np.linalg.lstsq(basis, dx[m], rcond=None)[0]
    return np.abs(dv), jumps, mid, np.minimum(v[k], v[k + 1]), np.maximum(v[k], v[k + 1])


def find_grid(v, x, train, v_lo: float, v_hi: float) -> tuple[float, float, float] | None:
    """``(spacing, phase, peak ratio)`` (V, V, –) of a regular grid of jumps in the record's training
    part — levels at ``phase + k·spacing`` — or None where the periodogram's peak is under
    :data:`MIN_COMB_RATIO` × its median (no comb: a smooth stage, or a drive of large steps)."""
    dv, jumps, mid, _, _ = _jump_increments(np.asarray(v, float), np.asarray(x, float), np.asarray(train, bool))
    if dv.size < 100:
        return None
    def line(spacing, harmonics):
        """(summed normalised amplitude of the first ``harmonics`` harmonics, phase of the first)."""
        ok = dv < 0.25 * spacing
        if ok.sum() < 100:
            return 0.0, 0.0
        e, angle = jumps[ok], 2.0 * np.pi * mid[ok] / spacing
        first = np.sum(e * np.exp(-1j * angle))
        total = abs(first) + sum(abs(np.sum(e * np.exp(-1j * h * angle))) for h in range(2, harmonics + 1))
        return total / (np.sqrt(np.sum(e**2) * e.size) + 1e-300), -np.angle(first) / (2.0 * np.pi) * spacing

    spacings = (v_hi - v_lo) / np.geomspace(MIN_LEVELS, MAX_LEVELS, N_TRIAL_SPACINGS)
    power = np.array([line(spacing, HARMONICS)[0] for spacing in spacings])
    best = int(np.argmax(power))
    ratio = float(power[best] / (np.median(power[power > 0]) + 1e-300)) if np.any(power > 0) else 0.0
    if ratio < MIN_COMB_RATIO or not EDGE_SHARE * spacings.size <= best < (1.0 - EDGE_SHARE) * spacings.size:
        return None  # no comb, or a peak at the edge of the trial spacings (the slope's leakage, not a grid)
    spacing = float(spacings[best])
    # a comb of ideal jumps has every harmonic: the sum peaks at a third or a half of the grid's
    # spacing as well. A grid of spacing s has no line at 1/(k·s); where one stands, the grid is k·s.
    fundamental = line(spacing, 1)[0]
    for k in (5, 4, 3, 2):
        if k * spacing <= (v_hi - v_lo) / MIN_LEVELS and line(k * spacing, 1)[0] >= SUBHARMONIC_SHARE * fundamental:
            spacing *= k
            break
    return spacing, float(line(spacing, 1)[1] % spacing), ratio


def grid_levels(spacing: float, phase: float, v_lo: float, v_hi: float) -> np.ndarray:
    """The grid's levels (V) from one below the training range's bottom to its top."""
    first = np.floor((v_lo - phase) / spacing)
    levels = phase + np.arange(first, np.ceil((v_hi - phase) / spacing)) * spacing
    return levels[levels <= v_hi]


class _LevelMove:
    """One threshold of ``levels`` moved with the others fixed: the relays that touch it (``touched``,
    ``pairs``), the window it may move in (``low``, ``high``: within a quarter ``spacing`` of it and
    between its neighbours, V) and its relays' columns with it at a candidate place."""

    def __init__(self, v_fine, block: int, levels, level: int, spacing: float):
        i_all, j_all = relay_pairs(levels.size)
        self.touched = np.flatnonzero((i_all == level) | (j_all == level))
        self.pairs = (i_all[self.touched], j_all[self.touched])
        below = levels[level - 1] if level > 0 else -np.inf
        above = levels[level + 1] if level + 1 < levels.size else np.inf
        self.low = max(below, levels[level] - 0.25 * spacing)
        self.high = min(above, levels[level] + 0.25 * spacing)
        self.v_fine, self.block, self.levels, self.level = v_fine, block, levels, level

    def columns(self, candidate) -> np.ndarray:
        """The touched relays' columns with the threshold at ``candidate`` (V)."""
        trial = self.levels.copy()
        trial[self.level] = candidate
        return sharp_columns(self.v_fine, trial, self.block, self.pairs)


def place_levels(v_fine, block: int, x, train, levels, spacing: float, solve, rss_bar: float | None = None):
    """Thresholds (V) placed one by one (:data:`PLACEMENT_SWEEPS` sweeps, the weights refitted by
    ``solve`` after each): each moves to just above the training voltage within a quarter
    ``spacing`` of it (and between its neighbours) that minimises the training error. Every such
    voltage is tried with the weights held (at most :data:`MAX_CANDIDATES`, evenly among them, then
    every one between the best one's neighbours); the best of these, the level's place now and
    :data:`REFIT_CANDIDATES` evenly spaced ones are tried again with the weights of the level's own
    relays refitted (non-negative): with the weights held, a level whose relays no training sample
    switched has no weight to move — a grid found 0.004 V below a triangle's lowest voltage left
    its relays never reset and its level there (4.2× the noise on training; 1.0× placed just above
    that voltage, development record 901/sharp_preisach/3).
    The placement starts from the grid as found or from every level just above its nearest training
    voltage, whichever fits better: with the weights held, levels that all sit on the wrong side of
    the drive's own voltages do not move one by one (a 25-level stage under triangles written on its
    nodes, development record 902/sharp_preisach/1: 5.7× the noise on training as found, 1.0× with
    the stage's own levels).
    ``solve(columns)`` fits the relay columns (non-negative) with the design's free columns and
    returns ``(the free columns' part of the prediction, the relay weights)``. None where the start
    fits the training part no better than ``rss_bar`` (m², a training residual sum of squares)."""
    levels = np.array(levels, dtype=np.float64)
    v_fine = np.asarray(v_fine, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    train = np.asarray(train, bool)
    v_train = training_voltages(v_fine, train, block)
    nudge = threshold_nudge(v_fine)

    def train_error(trial):
        cols = sharp_columns(v_fine, trial, block)
        base, w = solve(cols)
        return float(np.sum((base + cols @ w - x)[train] ** 2))

    # a drive written by a converter sits on the grid's own voltages, where which side of a shared
    # threshold a sample lies on is set by ties: the grid as found, or every level just above its
    # nearest training voltage, whichever fits the training part better, starts the placement
    snapped = snap_to_training(v_fine, train, block, levels)
    start_error = train_error(levels)
    if np.all(np.diff(snapped) > 0):
        snapped_error = train_error(snapped)
        if snapped_error < start_error:
            levels, start_error = snapped, snapped_error
    if rss_bar is not None and start_error >= rss_bar:
        return None
    for _ in range(PLACEMENT_SWEEPS):
        cols = sharp_columns(v_fine, levels, block)
        base, w = solve(cols)
        prediction = base + cols @ w
        for level in range(levels.size):
            move = _LevelMove(v_fine, block, levels, level, spacing)
            touched, trial_columns = move.touched, move.columns
            rest = prediction - cols[:, touched] @ w[touched]
            voltages = v_train[(v_train > move.low) & (v_train < move.high)] + nudge
            target = (x - rest)[train]

            def held_error(candidate):
                return float(np.sum((trial_columns(candidate)[train] @ w[touched] - target) ** 2))

            def refit(candidate):
                """(training error, the level's relay weights) with those weights refitted."""
                own = trial_columns(candidate)[train]
                gram = own.T @ own
                gram[np.diag_indices_from(gram)] += 1e-12 * (np.trace(gram) + 1e-300)
                r = np.linalg.cholesky(gram).T
                b = solve_triangular(r, own.T @ target, trans="T")
                weights, misfit = nnls(r, b)
                return float(target @ target - b @ b + misfit**2), weights

            coarse = voltages if voltages.size <= MAX_CANDIDATES else \
                voltages[np.linspace(0, voltages.size - 1, MAX_CANDIDATES).round().astype(int)]
            errors = np.array([held_error(c) for c in coarse])
            candidates = list(coarse[np.argsort(errors, kind="stable")[:1]])
            if voltages.size > MAX_CANDIDATES:
                k = int(np.argmin(errors))
                finer = voltages[(voltages > coarse[max(k - 1, 0)]) & (voltages < coarse[min(k + 1, coarse.size - 1)])]
                if finer.size:
                    candidates.append(finer[int(np.argmin([held_error(c) for c in finer]))])
            if voltages.size:
                candidates += list(voltages[np.linspace(0, voltages.size - 1, REFIT_CANDIDATES).round().astype(int)])
            best_error, best_weights = refit(levels[level])
            for candidate in dict.fromkeys(candidates):
                error, weights = refit(candidate)
                if error < best_error:
                    best_error, best_weights, levels[level] = error, weights, candidate
            w[touched] = best_weights
            cols[:, touched] = trial_columns(levels[level])
            prediction = rest + cols[:, touched] @ w[touched]
    return levels


def place_at_jumps(v, x, train, levels, spacing: float) -> np.ndarray:
    """Thresholds (V) of a fine grid placed where the record jumps: each, in turn from the bottom,
    just above the training voltage (within a quarter ``spacing`` of it, above the level placed
    below) that splits the training increments near it best — per direction, the displacement
    increment fitted as a local slope times the voltage increment plus a jump on the increments
    whose voltage span holds the threshold (least squares; the two directions' residuals summed;
    increments shorter than half a spacing that overlap the window). No relay weights are
    fitted: with more than :data:`FREE_LEVELS` levels the training-error placement
    (:func:`place_levels`) would refit hundreds of relays per level."""
    v, x, train = np.asarray(v, float), np.asarray(x, float), np.asarray(train, bool)
    k = np.flatnonzero(train[:-1] & train[1:])
    dv, dx = v[k + 1] - v[k], x[k + 1] - x[k]
    keep = (dv != 0) & (np.abs(dv) < 0.5 * spacing)
    k, dv, dx = k[keep], dv[keep], dx[keep]
    lo, hi, rising = np.minimum(v[k], v[k + 1]), np.maximum(v[k], v[k + 1]), dv > 0
    v_train = np.unique(v[train])
    nudge = threshold_nudge(v)
    placed = np.array(levels, dtype=np.float64)
    for level in range(placed.size):
        low = max(placed[level - 1] if level else -np.inf, levels[level] - 0.25 * spacing)
        high = levels[level] + 0.25 * spacing
        candidates = v_train[(v_train >= low) & (v_train < high)]
        near = (hi >= low) & (lo < high)
        if candidates.size == 0 or near.sum() < 4:
            continue
        misfit = np.zeros(candidates.size)
        for direction in (True, False):
            m = near & (rising == direction)
            if m.sum() < 2:
                continue
            a, y = np.abs(dv[m]), dx[m]
            b = ((lo[m][:, None] <= candidates[None, :]) & (candidates[None, :] < hi[m][:, None])).astype(float)
            aa, ay, yy = a @ a, a @ y, y @ y
            bb, ab, by = b.sum(axis=0), a @ b, y @ b
            det = aa * bb - ab**2
            with np.errstate(divide="ignore", invalid="ignore"):
                two = yy - (bb * ay**2 - 2.0 * ab * ay * by + aa * by**2) / det
            misfit += np.where(det > 1e-12 * aa * np.maximum(bb, 1.0), two, yy - ay**2 / aa)
        placed[level] = candidates[int(np.argmin(misfit))] + nudge
    return placed


def refine_fine_levels(v_fine, block: int, x, train, levels, spacing: float, solve) -> np.ndarray:
    """One sweep of a fine grid's thresholds (V) by the training error, the relay weights held: each
    level in turn moves to just above the training voltage among the :data:`FINE_CANDIDATES`
    nearest to it (within a quarter ``spacing``, between its neighbours) that fits the training part
    best. ``solve(levels)`` returns ``(prediction, per-relay weights)`` of the fit on ``levels``
    (the density's node weights spread to the relays, :func:`density_map`); only the relays of the
    level moved are simulated again, never the whole grid's states."""
    levels = np.array(levels, dtype=np.float64)
    v_fine, x, train = np.asarray(v_fine, dtype=np.float64), np.asarray(x, float), np.asarray(train, bool)
    v_train = training_voltages(v_fine, train, block)
    nudge = threshold_nudge(v_fine)
    prediction, w = solve(levels)
    for level in range(levels.size):
        move = _LevelMove(v_fine, block, levels, level, spacing)
        touched = move.touched
        current = move.columns(levels[level]) @ w[touched]
        rest = (prediction - current)[train]
        voltages = v_train[(v_train > move.low) & (v_train < move.high)]
        voltages = voltages[np.argsort(np.abs(voltages - levels[level]), kind="stable")[:FINE_CANDIDATES]] + nudge
        best, best_error = levels[level], float(np.sum((rest + current[train] - x[train]) ** 2))
        for candidate in voltages:
            error = float(np.sum((rest + (move.columns(candidate) @ w[touched])[train] - x[train]) ** 2))
            if error < best_error:
                best, best_error = candidate, error
        if best != levels[level]:
            levels[level] = best
            prediction = prediction - current + move.columns(best) @ w[touched]
    return levels


def tied_thresholds(v_fine, block: int, x, train, levels, spacing: float, prediction, weights,
                    tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """``(lowest, highest)`` thresholds (V, per level) whose training error, the relay weights held
    (per relay, ``weights``; ``prediction`` the fit's, m), lies within ``tolerance`` (m², a training
    residual sum of squares) of the placed level's: from each level outward, one training voltage
    at a time (within a quarter ``spacing``, between its neighbours, at most :data:`TIE_STEPS` each
    way), until one fits worse. Moving a threshold past a training voltage the training part visits
    only in states that the move does not change costs nothing, and one it visits rarely costs less
    than the noise: the training part does not tell such places apart, and a held-out voltage
    between them switches relays (or not) wherever the threshold lies there — on development record
    904/sharp_preisach/1 two places 2.2 mV apart fitted within 0.4 σ² of each other, and the one the
    placement took left the held-out part at 3.7× the noise (the other 1.1×)."""
    levels = np.asarray(levels, dtype=np.float64)
    v_fine, x, train = np.asarray(v_fine, dtype=np.float64), np.asarray(x, float), np.asarray(train, bool)
    v_train = training_voltages(v_fine, train, block)
    nudge = threshold_nudge(v_fine)
    lowest, highest = levels.copy(), levels.copy()
    for level in range(levels.size):
        move = _LevelMove(v_fine, block, levels, level, spacing)
        own = weights[move.touched]
        current = move.columns(levels[level]) @ own
        rest = (prediction - current)[train]
        placed_error = float(np.sum((rest + current[train] - x[train]) ** 2))

        def fits_as_well(candidate):
            part = (move.columns(candidate) @ own)[train]
            return float(np.sum((rest + part - x[train]) ** 2)) <= placed_error + tolerance

        down = v_train[(v_train > move.low) & (v_train < levels[level] - nudge / 2)][::-1][:TIE_STEPS]
        up = v_train[(v_train >= levels[level]) & (v_train < move.high)][:TIE_STEPS]
        for voltage in down:
            if not fits_as_well(voltage + nudge):
                break
            lowest[level] = voltage + nudge
        for voltage in up:
            if not fits_as_well(voltage + nudge):
                break
            highest[level] = voltage + nudge
    return lowest, highest
