"""Fitting the image forward model (:mod:`.model`) to a trace/retrace pair, training lines only.

Parameters: θ = [position coefficients, height gain, log10 of the non-linear effect parameters]
(``z_feedback``: ki; ``tip``: extra paraboloid radius; ``dynamics``: f0 and ζ), all fitted jointly
by Levenberg–Marquardt (:func:`scipy.optimize.least_squares`). Jacobian: analytic for positions and
gain, ``∂h/∂θ = Z'·(∂S/∂x·B_x + ∂S/∂y·B_y)`` with tangents carried through the Z loop; one-sided
finite differences (0.01 decade) for the non-linear parameters, which are held inside their search
ranges. Each position coefficient also has a vanishing prior row (θ/scale·1e-12 m) that only pins
coefficients the data leave undetermined (the slow-axis terms on a grating whose lines run along y).

Starting points:

* the baseline with the scenario reference: stage scale and offset per axis from a grid search of
  the measured column / row means against the reference's (periodic calibration standards have
  many local minima; among equal peaks the one nearest an origin-anchored scale), then
  Levenberg–Marquardt on the reference blurred by 2, 1 and ½ image pixel;
* a new non-linear effect: a joint fit from each of the best points of a grid ranked by matched
  filters on the linearised model (:func:`_scan`) and from its no-effect value; the best is kept;
* a new linear effect: 0, the rest from the model it is added to.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .model import Column, Layout, ZLoop, baseline_columns, effect_columns, filter_columns, resonance
from .reference import Surface, parabolic_dilation, trace_reference

__all__ = ["ImageDesign", "ImageFit", "fit_image", "redundancy", "LINEAR_EFFECTS"]

LINEAR_EFFECTS = ("creep", "drift", "cross_coupling", "asymmetry", "z_bow")
PRIOR = 1e-12  # m per prior-scale of a coefficient
FD_STEP = 0.01  # decades, finite-difference step of the non-linear parameters
SCAN_KEEP = {"dynamics": 2, "tip": 1, "z_feedback": 1}  # starts taken from each matched-filter ranking
BLURS = (2.0, 1.0, 0.5)  # image pixels, Gaussian σ of the reference in the baseline's coarse-to-fine start


class ImageDesign:
    """Data, frame layout, reference and known instrument of one diagnosis; caches re-dilated references.

    Parameters
    ----------
    record : ImageRecord
    layout : Layout
    reference : HeightMap or None
        Scenario reference surface (stage coordinates, m), or None for the trace reference.
    z_loop : ZLoop or None
        The known Z loop (None: ideal, recorded height = surface).
    tip_radius_m : float or None
        Apex radius of the known tip (m).
    sample : HeightMap or None
        The undilated sample when the known tip is a paraboloid of ``tip_radius_m`` (the ``tip``
        candidate then dilates it with the total radius), else None (it dilates ``reference``).
    baseline : {"asymmetric", "symmetric"}
    train, held : bool arrays (lines,)
        Lines the fits see, lines that score them.
    """

    def __init__(self, record, layout: Layout, reference, *, z_loop: ZLoop | None, tip_radius_m, baseline: str,
                 train: np.ndarray, held: np.ndarray, sample=None):
        self.record, self.layout = record, layout
        self.kind = "scenario" if reference is not None else "trace"
        self.reference, self.sample = reference, sample
        self.z_loop, self.tip_radius_m, self.baseline = z_loop, tip_radius_m, baseline
        self.train, self.held = train, held
        self.base_columns = baseline_columns(layout, baseline, self.kind)
        self.pixel_time_s = layout.m * layout.dt
        self.dx = record.pixel_size_m[0]
        self._surfaces: dict = {}
        lr = layout.geometry.line_rate_hz
        self.ranges = {"z_feedback": (0.2 / self.pixel_time_s, 1.5 * max(z_loop.ki_per_s if z_loop else 0.0,
                                                                           20.0 / self.pixel_time_s)),
                       "tip": (0.02 * self.dx, 20.0 * self.dx),
                       "f0": (16.0 * lr, 0.4 / layout.dt), "zeta": (0.01, 1.0)}

    def surface(self, extra_radius: float = 0.0, ki: float | None = None, blur: float = 0.0) -> Surface:
        """Reference surface with an extra paraboloid tip radius (m), blurred by ``blur`` image pixels (Gaussian σ);
        the trace reference is de-lagged for ``ki``."""
        key = (float(f"{extra_radius:.4g}"), ki if self.kind == "trace" else None, blur)
        if key not in self._surfaces:
            if len(self._surfaces) > 64:
                self._surfaces.clear()
            if self.kind == "scenario" and self.sample is not None and key[0] > 0:
                surf = Surface(parabolic_dilation(self.sample, self.tip_radius_m + key[0]))
            elif self.kind == "scenario":
                surf = Surface(parabolic_dilation(self.reference, key[0]))
            else:
                surf = trace_reference(self._delag(ki), self.dx, self.layout.geometry.pixel_centres_x[0])
            self._surfaces[key] = surf.smoothed(blur * self.dx) if blur else surf
        return self._surfaces[key]

    def _delag(self, ki):
        """Trace with the (linear) Z-loop lag along +x undone at pixel level; unchanged for an ideal loop."""
        tr = self.record.trace
        if ki is None:
            return tr
        kp = self.z_loop.kp if self.z_loop else 0.1
        a = np.exp(-ki * self.pixel_time_s / (1.0 + kp))
        out = tr.copy()
        out[:, 1:] = tr[:, :-1] + (tr[:, 1:] - tr[:, :-1]) / (1.0 - a)
        return out

    def rows(self, lines: np.ndarray, trace_img, retrace_img) -> np.ndarray:
        """Line-levelled pixels of ``lines`` (bool) in scan order — each line's trace, then its retrace
        (retrace only for the trace reference, whose trace is the input); images (lines, pixels[, c])
        → (rows[, c]).

        Each line of each direction has its mean removed, as AFM line levelling does: line-to-line
        height offsets (Z drift, Z-stage hysteresis) carry no information on the XY stage.
        """
        parts = [retrace_img] if self.kind == "trace" else [trace_img, retrace_img]
        sel = np.stack([np.asarray(img)[lines] for img in parts], axis=1)  # (lines, directions, pixels[, c])
        sel = sel - sel.mean(axis=2, keepdims=True)
        return sel.reshape(-1, *sel.shape[3:])


@dataclass
class ImageFit:
    """A fitted model: effects, columns, θ (positions, gain, log10 non-linear parameters) and their values."""

    effects: tuple
    columns: list
    theta: np.ndarray
    hyper: dict
    trace: np.ndarray = field(repr=False)
    retrace: np.ndarray = field(repr=False)
    x: np.ndarray = field(repr=False)
    y: np.ndarray = field(repr=False)
    rss_train: float = 0.0

    @property
    def n_params(self) -> int:
        """Fitted numbers: position coefficients, gain and non-linear parameters."""
        return int(self.theta.size)

    @property
    def gain(self) -> float:
        return float(self.theta[len(self.columns)])

    def coefficient(self, group: str, name: str) -> float:
        for k, c in enumerate(self.columns):
            if c.group == group and c.name == name:
                return float(self.theta[k])
        raise KeyError(f"{group}.{name}")


def _hyper_keys(effects) -> list[str]:
    """Names of the log10 non-linear parameters in θ order."""
    keys = []
    for e in effects:
        keys += {"dynamics": ["f0", "zeta"], "z_feedback": ["z_feedback"], "tip": ["tip"]}.get(e, [])
    return keys


class _Problem:
    """Residual and Jacobian of one model (columns, non-linear parameters) on some lines.

    The recorded height is ``g·h + Σ c_j·bz_j`` with ``h`` the Z-loop output and ``bz_j`` the height
    columns (``z_bow``), compared line-levelled (:meth:`ImageDesign.rows`).
    """

    def __init__(self, design: ImageDesign, columns: list[Column], keys: list[str], lines: np.ndarray, blur=0.0):
        self.design, self.columns, self.keys, self.lines, self.blur = design, columns, keys, lines, blur
        self.bx = np.ascontiguousarray(np.column_stack([c.bx for c in columns]))
        self.by = np.ascontiguousarray(np.column_stack([c.by for c in columns]))
        self.moves_x, self.moves_y = np.any(self.bx != 0, axis=0), np.any(self.by != 0, axis=0)
        self.zcols = np.array([k for k, c in enumerate(columns) if c.bz is not None], dtype=int)
        bz = np.column_stack([columns[k].bz for k in self.zcols]) if self.zcols.size else np.zeros((design.layout.n, 0))
        self.bz_img = design.layout.images(bz)  # (trace, retrace), each (lines, pixels, q)
        self.prior = np.array([PRIOR / c.scale for c in columns])
        self.p = len(columns)
        self.data = design.rows(lines, design.record.trace, design.record.retrace)

    def values(self, theta) -> dict:
        """Non-linear parameter values (clipped to their ranges) from θ."""
        out = {}
        for k, v in zip(self.keys, theta[self.p + 1:]):
            lo, hi = self.design.ranges[k]
            out[k] = float(10.0 ** np.clip(v, np.log10(lo), np.log10(hi)))
        return out

    def static(self, theta):
        """Positions (x, y) of every sample before the dynamics (m)."""
        lay = self.design.layout
        return lay.u + self.bx @ theta[: self.p], lay.v + self.by @ theta[: self.p]

    def _positions(self, theta, vals, cols, static=None):
        """Actual positions (x, y) of every sample and their derivatives (N, len(cols)) w.r.t. θ[cols]:
        filtered by the dynamics, and for the trace reference made relative to the trace's own."""
        lay = self.design.layout
        x, y = self.static(theta) if static is None else static
        dx, dy = self.bx[:, cols], self.by[:, cols]
        if "f0" in vals:
            b, a = resonance(vals["f0"], vals["zeta"], lay.dt)
            x, y = filter_columns(b, a, x), filter_columns(b, a, y)
            dx, dy = dx.copy(), dy.copy()
            for d, moving in ((dx, self.moves_x[cols]), (dy, self.moves_y[cols])):
                if moving.any():  # columns that never move an axis stay zero
                    d[:, moving] = filter_columns(b, a, d[:, moving])
        if self.design.kind == "trace":  # retrace relative to the trace at the same intended x; trace at intended x
            rt, mir = lay.retrace, lay.mirror[lay.retrace]
            x = x.copy()
            x[rt] += lay.u[mir] - x[mir]
            x[~rt] = lay.u[~rt]
            dx = dx.copy()
            dx[rt] -= dx[mir]
            dx[~rt] = 0.0
            y, dy = lay.line.astype(float), np.zeros_like(dy)
        return x, y, dx, dy

    def _loop(self, vals):
        ki = vals.get("z_feedback", self.design.z_loop.ki_per_s if self.design.z_loop else None)
        if ki is None:
            return None
        z = self.design.z_loop or ZLoop(ki)
        return ZLoop(ki, z.kp, z.setpoint_m)

    def surface(self, vals, blur: float = 0.0) -> Surface:
        """The reference for these non-linear values (tip radius; the trace reference de-lagged for the loop)."""
        loop = self._loop(vals)
        return self.design.surface(vals.get("tip", 0.0), None if loop is None else loop.ki_per_s, blur)

    def evaluate(self, theta, jac=False, cols=None):
        """Model images (lines, pixels) — predicted height, Z-loop height (the gain's column) and, with
        ``jac``, ∂/∂θ for the position coefficients ``cols`` (default all; lines, pixels, len(cols)) —
        each as a (trace, retrace) pair, and the positions (x, y) of every sample."""
        vals = self.values(theta)
        cols = np.arange(self.p) if cols is None else cols
        x, y, dx, dy = self._positions(theta, vals, cols if jac else cols[:0])
        surf = self.surface(vals, self.blur)
        s, sx, sy = surf.sample(x, y, gradient=jac)
        ds = sx[:, None] * dx + sy[:, None] * dy if jac else None
        loop = self._loop(vals)
        h, dh = (s, ds) if loop is None else loop.run(s, ds, self.design.layout.dt)
        g = theta[self.p]
        lay = self.design.layout
        hh = lay.images(h)
        cz = theta[self.zcols]
        pred = tuple(g * img + b @ cz for img, b in zip(hh, self.bz_img))
        dd = None
        if jac:
            dd = lay.images(dh)
            dd = (g * dd[0], g * dd[1])
            at = np.nonzero(np.isin(cols, self.zcols))[0]
            for j in at:  # height columns: their own signal (the position tangent is zero)
                z = int(np.nonzero(self.zcols == cols[j])[0][0])
                for img, b in zip(dd, self.bz_img):
                    img[..., j] += b[..., z]
        return pred, hh, dd, x, y

    def model_rows(self, theta, jac=False, cols=None):
        """Line-levelled rows of :meth:`evaluate`'s images on the problem's lines: (prediction, gain column, derivatives)."""
        pred, hh, dd, _, _ = self.evaluate(theta, jac, cols)
        rows = self.design.rows
        return rows(self.lines, *pred), rows(self.lines, *hh), (rows(self.lines, *dd) if jac else None)

    def residual(self, theta):
        return np.concatenate([self.data - self.model_rows(theta)[0], self.prior * theta[: self.p]])

    def jacobian(self, theta):
        m, mh, md = self.model_rows(theta, jac=True)
        cols = [md, mh[:, None]]
        for k in range(len(self.keys)):
            step = theta.copy()
            step[self.p + 1 + k] += FD_STEP
            cols.append(((self.model_rows(step)[0] - m) / FD_STEP)[:, None])
        top = -np.hstack(cols)
        bottom = np.zeros((self.p, top.shape[1]))
        bottom[:, : self.p] = np.diag(self.prior)
        return np.vstack([top, bottom])

    def rss(self, theta) -> float:
        return float(np.sum((self.data - self.model_rows(theta)[0]) ** 2))

    def solve(self, theta0, max_nfev=40):
        sol = least_squares(self.residual, theta0, jac=self.jacobian, method="lm", x_scale="jac", xtol=1e-7, ftol=1e-9,
                            max_nfev=max_nfev)
        return sol.x, float(np.sum(sol.fun[: self.data.size] ** 2))

    def gain(self, theta) -> np.ndarray:
        """θ with the height gain solved by least squares for fixed positions."""
        h = self.model_rows(theta)[1]
        theta = theta.copy()
        theta[self.p] = float(h @ self.data / (h @ h))
        return theta


def _stage_scales(design: ImageDesign, fit: "ImageFit | None") -> tuple[float, float]:
    """Mean actual/intended slope per axis of a fit's positions (1 without a fit or for the trace reference)."""
    lay = design.layout
    if fit is None or design.kind == "trace":
        return (1.0, 1.0)
    return float(np.polyfit(lay.u, fit.x, 1)[0]), float(np.polyfit(lay.v, fit.y, 1)[0])


def _columns_for(design: ImageDesign, effects, start: "ImageFit | None") -> list[Column]:
    cols = list(design.base_columns)
    for e in effects:
        if e not in LINEAR_EFFECTS:
            continue
        old = [c for c in (start.columns if start else []) if c.group == e]
        if not old:
            x_fit, y_fit = (start.x, start.y) if start else (design.layout.u, design.layout.v)
            old = effect_columns(design.layout, e, design.baseline, x_fit=x_fit, y_fit=y_fit,
                                 scales=_stage_scales(design, start), reference=design.kind)
        cols += old
    return cols


def _coarse_axis(measured, intended, ref_coord, ref_profile):
    """(scale, offset): ``reference coordinate = scale·intended + offset`` that best correlates the two mean
    profiles. The stage sits at 0 when undriven, so its scale error is anchored at the origin: among
    near-equal correlation peaks (a periodic sample repeats every period) the smallest offset wins."""
    if np.std(measured) <= 1e-6 * (np.ptp(ref_profile) or 1.0):
        return 1.0, 0.0
    step = ref_coord[1] - ref_coord[0]
    m = measured - measured.mean()
    found = []
    for a in np.arange(0.5, 1.5001, 0.01):
        pos = a * intended
        offsets = np.arange(ref_coord[0] - pos.min(), ref_coord[-1] - pos.max(), step)
        if offsets.size == 0:
            continue
        vals = np.interp(pos[None, :] + offsets[:, None], ref_coord, ref_profile)
        vals = vals - vals.mean(axis=1, keepdims=True)
        corr = vals @ m / (np.linalg.norm(vals, axis=1) * np.linalg.norm(m) + 1e-300)
        found += [(float(c), float(a), float(o)) for c, o in zip(corr, offsets)]
    top = max(c for c, _, _ in found)
    near = [f for f in found if f[0] >= top - 0.01 * abs(top)]
    _, a, o = min(near, key=lambda f: abs(f[2]))
    return a, o


def _coarse_start(design: ImageDesign) -> dict:
    """Initial stage scale/offset coefficients (P0, P1 of x and y) from mean profiles (scenario reference)."""
    ref, rec, g = design.reference, design.record, design.layout.geometry
    use = design.train
    rows = (ref.y >= g.offset[1]) & (ref.y <= g.offset[1] + g.size[1])
    ax, ox = _coarse_axis(rec.trace[use].mean(axis=0), g.pixel_centres_x, ref.x, ref.z[rows].mean(axis=0))
    cols = (ref.x >= ax * g.offset[0] + ox) & (ref.x <= ax * (g.offset[0] + g.size[0]) + ox)
    ay, oy = _coarse_axis(rec.trace[use].mean(axis=1), g.line_centres_y[use], ref.y, ref.z[:, cols].mean(axis=1))
    cx, cy = g.offset[0] + g.size[0] / 2, g.offset[1] + g.size[1] / 2
    init = {"y_P0": (ay - 1.0) * cy + oy, "y_P1": (ay - 1.0) * g.size[1] / 2}
    for prefix in ("trace_", "retrace_", "mean_"):
        init[prefix + "P0"], init[prefix + "P1"] = (ax - 1.0) * cx + ox, (ax - 1.0) * g.size[0] / 2
    return init


def _ringing(layout: Layout, f0: float, zeta: float) -> np.ndarray:
    """Damped oscillations (N, 4) at (f0, ζ) after every turnaround — x sine and cosine, signed by the
    new scan direction — and after every line step — y sine and cosine; unit amplitude."""
    w0 = 2.0 * np.pi * f0
    half = layout.n // (2 * layout.shape[0])
    tau = (np.arange(half) + 0.5) * layout.dt  # the same for every half-line
    decay = np.exp(-zeta * w0 * tau)
    wd = w0 * np.sqrt(max(1.0 - zeta * zeta, 1e-6))
    wave = np.stack([decay * np.sin(wd * tau), decay * np.cos(wd * tau)], axis=-1)  # (half, 2)
    out = np.zeros((layout.shape[0], 2, half, 4))
    out[:, 0, :, :2] = wave  # trace: the scan direction turned to +x
    out[:, 1, :, :2] = -wave
    out[:, 0, :, 2:] = wave  # the y step happens at each trace start
    return out.reshape(layout.n, 4)


def _signatures(base: "_Problem", th, static, effect: str, s, sx, sy):
    """Grid points of a new non-linear ``effect`` (log10 values) and a function giving, for point k, the
    blocks of sample-level signature columns whose free amplitudes a matched filter fits (see
    :func:`_scan`; made on demand: a 256 × 256 frame has ~0.5 M samples, hundreds of points);
    ``static`` are the current positions before any dynamics, ``s, sx, sy`` the surface and its
    gradient there."""
    d, vals = base.design, base.values(th)
    if effect == "dynamics":
        lo, hi = d.ranges["f0"]
        f0s = np.geomspace(lo, hi, int(np.ceil(np.log(hi / lo) / np.log(1.04))) + 1)
        points = [(f, z) for z in (0.02, 0.05, 0.12, 0.3) for f in f0s]
        x0, y0, _, _ = base._positions(th, vals, np.arange(0), static)
        gradients = np.column_stack([sx, sx, sy, sy])

        def blocks(point):
            x, y, _, _ = base._positions(th, dict(vals, f0=point[0], zeta=point[1]), np.arange(0), static)
            return [np.column_stack([sx * (x - x0), sy * (y - y0)]), _ringing(d.layout, *point) * gradients]
        return [{"f0": np.log10(f), "zeta": np.log10(z)} for f, z in points], lambda k: blocks(points[k])
    lo, hi = d.ranges[effect]
    values = np.geomspace(lo, hi, 16)
    x, y, _, _ = base._positions(th, vals, np.arange(0), static)
    if effect == "tip":
        def column(v):
            return base.surface(dict(vals, tip=v)).sample(x, y, gradient=False)[0] - s
    else:  # z_feedback: the height change of the loop itself, at the current surface heights
        now = base._loop(vals)
        h0 = s if now is None else now.run(s, None, d.layout.dt)[0]
        z = d.z_loop or ZLoop(hi)

        def column(v):
            return ZLoop(v, z.kp, z.setpoint_m).run(s, None, d.layout.dt)[0] - h0
    return [{effect: np.log10(v)} for v in values], lambda k: [column(values[k])[:, None]]


def _null_point(design: ImageDesign, effect: str) -> dict:
    """The values (log10) at which a non-linear effect changes (next to) nothing: the fit with it then starts
    from the model it is added to and cannot end worse."""
    r = design.ranges
    if effect == "dynamics":
        return {"f0": np.log10(r["f0"][1]), "zeta": np.log10(0.7)}
    if effect == "tip":
        return {"tip": np.log10(r["tip"][0])}
    return {"z_feedback": np.log10(design.z_loop.ki_per_s if design.z_loop else r["z_feedback"][1])}


def _scan(prob: "_Problem", theta, effect: str, keep: int) -> list[dict]:
    """Promising starting values of a new non-linear ``effect``, as log10 values, best first.

    At the current positions a non-linear effect often looks worse than none: the hysteresis
    polynomials and the gain have absorbed part of it (a lag, a broadened edge, the ringing of a
    resonance, whose fit error is moreover multimodal in f0 with basins a few per cent wide). Each
    grid point (dynamics: 4 % f0 steps × 4 ζ; tip, z_feedback: 16 log-spaced values) is therefore
    scored as a matched filter on the current model linearised in all its position coefficients:
    the effect's signature with a free amplitude, the residual and the signature projected off the
    Jacobian. Dynamics has two signatures — the resonance's own change of the x and y positions (two
    amplitudes), and free sine/cosine amplitudes of the damped oscillation (:func:`_ringing`) — and
    the ``keep`` best of each ranking are returned (they disagree when the ringing is faint).
    """
    d = prob.design
    others = [k for k in prob.keys if k not in _hyper_keys((effect,))]
    base = _Problem(d, prob.columns, others, prob.lines)
    th = np.r_[theta[: prob.p + 1], [theta[prob.p + 1 + prob.keys.index(k)] for k in others]]
    vals = base.values(th)
    m, mh, md = base.model_rows(th, jac=True)
    q, _ = np.linalg.qr(np.column_stack([mh, md]))
    r = base.data - m
    r -= q @ (q.T @ r)
    static = base.static(th)
    x, y, _, _ = base._positions(th, vals, np.arange(0), static)
    s, sx, sy = base.surface(vals).sample(x, y)
    points, blocks = _signatures(base, th, static, effect, s, sx, sy)
    loop, g = base._loop(vals), th[base.p]
    scores = np.full((len(points), 2), np.inf)
    for start in range(0, len(points), 16):
        chunk = [blocks(k) for k in range(start, min(start + 16, len(points)))]
        cols = np.hstack([b for point in chunk for b in point])
        dh = cols if (loop is None or effect == "z_feedback") else loop.run(s, cols, d.layout.dt)[1]
        jk = d.rows(prob.lines, *d.layout.images(g * dh))
        jk -= q @ (q.T @ jk)
        at = 0
        for k, point in enumerate(chunk):
            for j, b in enumerate(point):
                a = jk[:, at:at + b.shape[1]]
                at += b.shape[1]
                coef = np.linalg.lstsq(a, r, rcond=None)[0]
                scores[start + k, j] = float(np.sum((r - a @ coef) ** 2))
    best = list(dict.fromkeys([int(k) for j in range(scores.shape[1]) if np.isfinite(scores[:, j]).all()
                               for k in np.argsort(scores[:, j])[:keep]]))
    return [points[k] for k in best]


def _theta(columns, keys, start: "ImageFit | None", init: dict) -> np.ndarray:
    """θ for ``columns`` and ``keys`` from a previous fit's values, then ``init`` (by name), else 0 (gain 1)."""
    prev = {}
    if start is not None:
        prev = {(c.group, c.name): v for c, v in zip(start.columns, start.theta)}
        prev.update({("hyper", k): v for k, v in zip(_hyper_keys(start.effects), start.theta[len(start.columns) + 1:])})
        prev[("gain", "")] = start.gain
    theta = np.array([prev.get((c.group, c.name), init.get(c.name, 0.0)) for c in columns]
                     + [prev.get(("gain", ""), 1.0)] + [prev.get(("hyper", k), init.get(k, 0.0)) for k in keys])
    return theta


def _finish(problem: _Problem, effects, theta, rss) -> ImageFit:
    (tr, rt), _, _, x, y = problem.evaluate(theta)
    vals = problem.values(theta)
    hyper = {}
    if "f0" in vals:
        hyper["dynamics"] = (vals["f0"], vals["zeta"])
    for k in ("z_feedback", "tip"):
        if k in vals:
            hyper[k] = vals[k]
    return ImageFit(tuple(effects), problem.columns, theta, hyper, tr, rt, x, y, rss)


def fit_image(design: ImageDesign, effects=(), start: ImageFit | None = None) -> ImageFit:
    """Fit the model with ``effects`` on the training lines; ``start`` (a fit with a subset of the
    effects) supplies the starting point."""
    effects = tuple(effects)
    columns = _columns_for(design, effects, start)
    keys = _hyper_keys(effects)
    prob = _Problem(design, columns, keys, design.train)
    if start is None:
        init = _coarse_start(design) if design.kind == "scenario" else {}
        theta = _theta(columns, keys, None, init)
        if design.kind == "scenario":
            for blur in BLURS:  # coarse to fine: wide edges first, so that each edge finds its own
                blurred = _Problem(design, columns, keys, design.train, blur=blur)
                theta, _ = blurred.solve(blurred.gain(theta), max_nfev=30)
        else:
            theta = prob.gain(theta)
    else:
        theta = _theta(columns, keys, start, {})
    old = set(_hyper_keys(start.effects)) if start else set()
    for e in effects:
        if not [k for k in _hyper_keys((e,)) if k not in old]:
            continue
        fits = []
        for point in _scan(prob, theta, e, keep=SCAN_KEEP[e]) + [_null_point(design, e)]:
            trial = theta.copy()
            for k, v in point.items():
                trial[prob.p + 1 + keys.index(k)] = v
            fits.append(prob.solve(trial))  # a deep narrow basin can look worse than a broad one early on
        theta = min(fits, key=lambda tr: tr[1])[0]
    theta, rss = prob.solve(theta)
    return _finish(prob, effects, theta, rss)


def redundancy(design: ImageDesign, start: ImageFit, effect: str) -> float:
    """How much of a linear ``effect``'s signature the model ``start`` cannot already produce.

    The norm of the effect's Jacobian columns (training lines, at ``start``) left after projecting
    out the model's own columns, relative to their norm: 0 means the effect is indistinguishable
    from what the model has (e.g. drift and cross-coupling on a sample that does not vary along
    y). 1 for non-linear effects (checked by their fit instead).
    """
    if effect not in LINEAR_EFFECTS:
        return 1.0
    columns = _columns_for(design, start.effects + (effect,), start)
    keys = _hyper_keys(start.effects)
    prob = _Problem(design, columns, keys, design.train)
    jac = prob.jacobian(_theta(columns, keys, start, {}))[: prob.data.size]
    new = np.array([c.group == effect for c in columns] + [False] * (1 + len(keys)))
    a, b = jac[:, ~new], jac[:, new]
    if not np.any(b):
        return 0.0
    left = b - a @ np.linalg.lstsq(a, b, rcond=None)[0]
    return float(np.linalg.norm(left) / np.linalg.norm(b))
