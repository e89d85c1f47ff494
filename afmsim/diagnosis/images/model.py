"""Forward model of a trace/retrace pair: intended raster → actual tip positions → surface → Z loop → pixels.

The frame is laid out as the simulator's raster (:func:`afmsim.scan.raster_trajectory`: trace
left → right, retrace back, y stepping at each trace start, ``SUBSAMPLES`` time samples per pixel).
For every sample the model computes the actual tip position

    x = F(x_int + B_x θ),   y = F(y_int + B_y θ)

— linear in the position parameters θ; F is the identity, or the ``dynamics`` resonance — reads
the reference surface there (:class:`~afmsim.diagnosis.images.reference.Surface`), runs the Z loop
(:class:`ZLoop`) along time and averages each pixel's samples; heights are ``g·z + h0`` (Z
calibration gain and offset, both fitted).

Columns of ``B`` (each a named group):

* baseline — rate-independent hysteresis as a Legendre polynomial (degree ``MAP_DEGREE``) of the
  intended x, one per scan direction (``asymmetric``), or mean branch with odd and half-width with
  even terms only (``symmetric``, a centrally symmetric loop); the slow axis ``y = y_int + P₂(y_int)``
  (its own rate-independent scale error and curvature);
* ``asymmetry`` — the terms the symmetric baseline lacks (even mean-branch, odd half-width terms);
* ``creep`` — γ · Σ Δx(s)·log10(1 + (t − s)/τ0) over the whole intended path from rest (approach
  included), both axes, scaled by the baseline's mean stage scale per axis: log-law creep by
  superposition, τ0 = ``CREEP_TAU0_S``; reported γ is per decade;
* ``drift`` — ``r·(t − t_mid)`` on x (m/s). A drift along y is a change of the slow-axis scale and is
  absorbed by the baseline's y polynomial;
* ``cross_coupling`` — ``x += c·(y − ȳ)``, ``y += c·(x − x̄)`` with the current model's positions;
* ``z_bow`` — not a position but a height term (``Column.bz``): a smooth background along x that
  differs between the scan directions, ``Σ_k c_k·P_k(x_int)`` for k = 1…``BOW_DEGREE``, on the
  retrace relative to the trace (trace reference) or per direction (scenario reference: the mean
  of both and their half-difference). It is what Z-piezo hysteresis/creep does on a line that
  sweeps a Z range (a tilted sample: trace and retrace run the Z loop's two branches, a lens-shaped
  difference up to 10–15 % of the range swept), what Z drift within a line does (a tilt between
  trace and retrace) and what out-of-plane scanner bow does (5–50 nm over 100 µm, datasheet).
  Line levelling removes its P0 (line-to-line offsets).

Non-linear (hyper-)parameters: ``dynamics`` (F = ω0²/(s² + 2ζω0 s + ω0²), Tustin with pre-warping),
``z_feedback`` (the loop's ``ki``), ``tip`` (extra paraboloid radius, the reference is re-dilated).

With the ``trace`` reference only the retrace is predicted, at positions relative to the trace's
own (every column enters as retrace minus its mirror trace sample), so effects that move trace and
retrace alike cancel, as they must.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit
from numpy.polynomial import legendre
from scipy.signal import bilinear, fftconvolve, lfilter, lfilter_zi

from afmsim.scan import RasterGeometry, raster_trajectory

__all__ = ["Layout", "ZLoop", "Column", "baseline_columns", "effect_columns", "resonance", "SUBSAMPLES",
           "MAP_DEGREE", "CREEP_TAU0_S", "BOW_DEGREE"]

SUBSAMPLES = 4
MAP_DEGREE = 5
Y_DEGREE = 2
CREEP_TAU0_S = 0.01
BOW_DEGREE = 3


class Layout:
    """Times and intended positions of every sample of the frame (SI units).

    Attributes: ``t`` (s from the frame start), ``u``/``v`` (intended x/y, m), ``retrace`` (bool),
    ``line`` (index), ``mirror`` (index of the trace sample at the same intended position of the
    same line), ``dt`` (sample interval, s), ``path_t``/``path_x``/``path_y`` (the whole intended
    path from rest, approach included) and ``frame_start`` (its first frame sample).
    """

    def __init__(self, shape, scan_size_m, offset_m, line_rate_hz, approach_s, subsamples=SUBSAMPLES):
        ny, nx = shape
        self.geometry = RasterGeometry(size=tuple(scan_size_m), offset=tuple(offset_m), pixels=nx, lines=ny,
                                       line_rate_hz=line_rate_hz, samples_per_pixel=subsamples, approach_s=approach_s)
        traj = raster_trajectory(self.geometry)
        f = traj.frame_start
        self.shape, self.m = (ny, nx), subsamples
        self.path_t, self.path_x, self.path_y, self.frame_start = traj.t, traj.x, traj.y, f
        self.t = traj.t[f:] - traj.t[f]
        self.u, self.v = traj.x[f:], traj.y[f:]
        self.n = self.t.size
        self.dt = 1.0 / self.geometry.sample_rate_hz
        idx = np.arange(self.n).reshape(ny, 2, nx * subsamples)
        self.retrace = np.zeros(self.n, dtype=bool)
        self.retrace[idx[:, 1].ravel()] = True
        self.line = np.repeat(np.arange(ny), 2 * nx * subsamples)
        self.mirror = np.arange(self.n)
        self.mirror[idx[:, 1].ravel()] = idx[:, 0, ::-1].ravel()
        w, h = self.geometry.size
        self.un = (self.u - (offset_m[0] + w / 2)) / (w / 2)
        self.vn = (self.v - (offset_m[1] + h / 2)) / (h / 2)

    def images(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel means of per-sample ``values`` (N[, p]) → (trace, retrace), each (lines, pixels[, p]), left → right."""
        ny, nx = self.shape
        frame = values.reshape(ny, 2, nx, self.m, *values.shape[1:])
        total = frame[:, :, :, 0].copy()
        for k in range(1, self.m):  # a running sum: faster than a mean over a short axis
            total += frame[:, :, :, k]
        total /= self.m
        return total[:, 0], total[:, 1, ::-1]


@dataclass(frozen=True)
class Column:
    """One basis column: its group (``baseline`` or an effect), name, x/y position signals (N,) and, for
    a height term, the height signal ``bz`` (N,; m per unit coefficient, added after the Z loop and the
    height gain)."""

    group: str
    name: str
    bx: np.ndarray
    by: np.ndarray
    scale: float  # plausible magnitude of the coefficient (prior width)
    bz: np.ndarray | None = None


def _mapping(layout: Layout, degree: int, which: str) -> list[tuple[str, np.ndarray]]:
    """Direction-resolved Legendre terms of the intended x: ``which`` ∈ trace, retrace, mean, width."""
    p = legendre.legvander(layout.un, degree)
    sign = np.where(layout.retrace, 1.0, -1.0)
    if which == "trace":
        return [(f"trace_P{k}", p[:, k] * ~layout.retrace) for k in range(degree + 1)]
    if which == "retrace":
        return [(f"retrace_P{k}", p[:, k] * layout.retrace) for k in range(degree + 1)]
    if which == "mean":
        return [(f"mean_P{k}", p[:, k]) for k in range(degree + 1)]
    return [(f"width_P{k}", p[:, k] * sign) for k in range(degree + 1)]


def baseline_columns(layout: Layout, kind: str, reference: str) -> list[Column]:
    """Rate-independent hysteresis columns (x) and the slow-axis polynomial (y) of the baseline."""
    zeros = np.zeros(layout.n)
    if kind == "asymmetric":
        terms = _mapping(layout, MAP_DEGREE, "retrace") if reference == "trace" else \
            _mapping(layout, MAP_DEGREE, "trace") + _mapping(layout, MAP_DEGREE, "retrace")
    else:  # centrally symmetric loop: odd mean branch (+ offset), even half-width
        mean = [c for k, c in enumerate(_mapping(layout, MAP_DEGREE, "mean")) if k == 0 or k % 2]
        width = [c for k, c in enumerate(_mapping(layout, MAP_DEGREE, "width")) if k % 2 == 0]
        terms = width if reference == "trace" else mean + width
    cols = [Column("baseline", n, b, zeros, 1e-6) for n, b in terms]
    if reference != "trace":
        yp = legendre.legvander(layout.vn, Y_DEGREE)
        cols += [Column("baseline", f"y_P{k}", zeros, yp[:, k], 1e-6) for k in range(Y_DEGREE + 1)]
    return cols


def _creep_signal(layout: Layout, path: np.ndarray) -> np.ndarray:
    """Σ Δpath(s)·log10(1 + (t − s)/τ0) over the whole path from rest, frame part (m per unit γ)."""
    kernel = np.log10(1.0 + layout.path_t / CREEP_TAU0_S)
    steps = np.diff(path, prepend=0.0)
    return fftconvolve(steps, kernel)[: path.size][layout.frame_start:]


def bow_columns(layout: Layout, reference: str) -> list[Column]:
    """Height columns of ``z_bow``: P1…P_BOW_DEGREE of the intended x on the retrace (trace reference),
    or as the mean of both directions and their half-difference (scenario reference); 1 m per unit."""
    zeros = np.zeros(layout.n)
    p = legendre.legvander(layout.un, BOW_DEGREE)[:, 1:]
    if reference == "trace":
        return [Column("z_bow", f"retrace_P{k + 1}", zeros, zeros, 1e-8, p[:, k] * layout.retrace)
                for k in range(BOW_DEGREE)]
    sign = np.where(layout.retrace, 1.0, -1.0)
    return [Column("z_bow", f"{which}_P{k + 1}", zeros, zeros, 1e-8, p[:, k] * w)
            for which, w in (("mean", 1.0), ("width", sign)) for k in range(BOW_DEGREE)]


def effect_columns(layout: Layout, effect: str, kind: str, *, x_fit=None, y_fit=None, scales=(1.0, 1.0),
                   reference: str = "scenario") -> list[Column]:
    """Columns of a linear ``effect`` (creep, drift, cross_coupling, asymmetry, z_bow); [] for the others.

    ``x_fit``/``y_fit`` are the current model's positions (m) and ``scales`` its mean stage scale
    (actual/intended) per axis; creep and cross-coupling act on the actual motion. ``reference``
    (``scenario``/``trace``) lays out the height columns of ``z_bow``.
    """
    zeros = np.zeros(layout.n)
    if effect == "z_bow":
        return bow_columns(layout, reference)
    if effect == "creep":
        return [Column("creep", "gamma", scales[0] * _creep_signal(layout, layout.path_x),
                       scales[1] * _creep_signal(layout, layout.path_y), 0.02)]
    if effect == "drift":
        return [Column("drift", "rate", layout.t - layout.t.mean(), zeros, 1e-8)]
    if effect == "cross_coupling":
        return [Column("cross_coupling", "coefficient", y_fit - y_fit.mean(), x_fit - x_fit.mean(), 0.01)]
    if effect == "asymmetry" and kind == "symmetric":
        mean = [c for k, c in enumerate(_mapping(layout, MAP_DEGREE, "mean")) if k > 0 and k % 2 == 0]
        width = [c for k, c in enumerate(_mapping(layout, MAP_DEGREE, "width")) if k % 2]
        return [Column("asymmetry", n, b, zeros, 1e-6) for n, b in mean + width]
    return []


@lru_cache(maxsize=1024)
def resonance(f0_hz: float, zeta: float, dt: float):
    """Discrete ω0²/(s² + 2ζω0 s + ω0²): bilinear transform pre-warped so the resonance sits at f0 (cached)."""
    wd = 2.0 * np.pi * f0_hz
    wa = 2.0 / dt * np.tan(wd * dt / 2.0)
    b, a = bilinear([wa * wa], [1.0, 2.0 * zeta * wa, wa * wa], fs=1.0 / dt)
    b.flags.writeable = a.flags.writeable = False  # shared through the cache
    return b, a


def filter_columns(b, a, cols: np.ndarray) -> np.ndarray:
    """Filter signals along time (axis 0), starting at rest at their first value."""
    zi = lfilter_zi(b, a)
    zi = zi[:, None] * cols[0][None, :] if cols.ndim == 2 else zi * cols[0]
    return lfilter(b, a, cols, axis=0, zi=zi)[0]


@njit(cache=True, nogil=True)
def _z_kernel(s, ds, dt, ki, kp, sp, nsub, h, dh):  # pragma: no cover - compiled
    """Z loop along the sample sequence; tangents ``dh = ∂h/∂θ`` from ``ds`` (N, p).

    The heights are exact per sub-step. The tangents are propagated once per sample, with the
    surface tangent held at the sample's own value over its sub-steps (a Jacobian approximation
    that only affects Gauss–Newton's convergence, not the fitted optimum).
    """
    n, p = ds.shape
    g = 1.0 + kp
    a = np.exp(-ki * dt / nsub / g)
    fall = ki * sp * dt / nsub
    q = kp / g
    jv = s[0]
    dj = ds[0].copy()
    for k in range(n):
        k0 = k - 1 if k > 0 else 0
        k1 = k + 1 if k + 1 < n else n - 1
        acc = 0.0
        alpha, beta = 1.0, 0.0  # running ∂J/∂J_start and ∂J/∂s_k over the sub-steps
        alpha_h, beta_h = 0.0, 0.0
        for j in range(nsub):
            frac = (j + 0.5) / nsub - 0.5
            other = k0 if frac < 0.0 else k1
            w = abs(frac)
            sj = (1.0 - w) * s[k] + w * s[other]
            if (sj - jv) / g > -sp:
                jv = sj + (jv - sj) * a
                alpha, beta = a * alpha, a * beta + (1.0 - a)
            else:  # tip off the surface: the integrator falls at ki·setpoint until it touches again
                floor = sj + g * sp
                if jv - fall >= floor:
                    jv -= fall
                else:  # touches within the sub-step: relax for the remaining fraction of it
                    jv = sj + (floor - sj) * a ** (1.0 - (jv - floor) / fall)
                    alpha, beta = 0.0, 1.0
            e = (sj - jv) / g
            if e > -sp:
                acc += jv + kp * e
                alpha_h += (1.0 - q) * alpha
                beta_h += (1.0 - q) * beta + q
            else:
                acc += jv - kp * sp
                alpha_h += alpha
                beta_h += beta
        h[k] = acc / nsub
        for c in range(p):
            dh[k, c] = (alpha_h * dj[c] + beta_h * ds[k, c]) / nsub
            dj[c] = alpha * dj[c] + beta * ds[k, c]


@dataclass(frozen=True)
class ZLoop:
    """Contact-mode Z loop as the image sees it (heights in m).

    ``dJ/dt = ki·e``, ``e = max((s − J)/(1 + kp), −setpoint)``, recorded ``h = J + kp·e``: a first-order
    lag of time constant (1 + kp)/ki while the tip touches, and a fall limited to ki·setpoint when it
    leaves the surface (parachuting at downhill edges). Each sample is the mean over sub-steps
    spanning its interval, the surface linear between samples; the relaxation is exact per sub-step.
    Not modelled: Z-stage hysteresis and resonance, detection noise.
    """

    ki_per_s: float
    kp: float = 0.1
    setpoint_m: float = 20e-9

    def run(self, s: np.ndarray, ds: np.ndarray | None, dt: float):
        """Recorded heights (N,) for surface heights ``s`` (N,) and tangents (N, p) for ``ds``."""
        nsub = max(2, int(np.ceil(2.0 * self.ki_per_s * dt / (1.0 + self.kp))))
        d = np.zeros((s.size, 0)) if ds is None else np.ascontiguousarray(ds)
        h, dh = np.empty(s.size), np.empty_like(d)
        _z_kernel(np.ascontiguousarray(s), d, dt, self.ki_per_s, self.kp, self.setpoint_m, nsub, h, dh)
        return h, (None if ds is None else dh)
