"""Reference surfaces of the image diagnosis: what the tip traces, as a function of its *actual* position.

Two kinds, both sampled by :class:`Surface` (bilinear between grid points, as the simulator reads
its surface, with the interpolant's exact gradient for the Gauss–Newton Jacobian):

* **scenario** — the scenario's sample (:func:`afmsim.experiment.build_sample`, stage coordinates,
  the scan window plus a margin) dilated by the scenario's tip (:func:`afmsim.tip.dilate`): the
  user says which calibration standard was imaged, so absolute positions (stage scale, slow-axis
  skew, tip broadening) become observable;
* **trace** — the measured trace image itself, each line its own reference at the intended pixel
  positions (rows fixed, no slow-axis information): only the trace→retrace relation is observable.

:func:`parabolic_dilation` is the ``tip`` candidate: the reference dilated by an extra paraboloid of
apex radius ΔR. A paraboloid ``r²/2R`` is separable (``x²/2R + y²/2R``), so the 2-D grey-scale
dilation is done as two 1-D dilations (:func:`scipy.ndimage.grey_dilation`, rows then columns), and
paraboloids compose, ``P_R0 ⊕ P_ΔR = P_(R0+ΔR)`` (exactly in the continuum, to (dx/2)²·(1/R0 + 1/ΔR)
on a grid of pitch dx). Not modelled: a conical flank (a cone tip broadens steep walls less than its
apex paraboloid would).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage

from afmsim.samples.heightmap import HeightMap

__all__ = ["Surface", "parabolic_dilation", "scenario_reference", "trace_reference"]


@njit(cache=True, nogil=True)
def _bilinear(z, rows, cols, out, gr, gc):  # pragma: no cover - compiled
    """Bilinear interpolation of ``z`` at fractional (row, col) and its exact partial derivatives.

    Coordinates are clamped to the grid (edge values beyond it, zero derivative across the clamp).
    """
    ny, nx = z.shape
    for k in range(rows.shape[0]):
        r, c = rows[k], cols[k]
        clamp_r = r < 0.0 or r > ny - 1.0
        clamp_c = c < 0.0 or c > nx - 1.0
        r = min(max(r, 0.0), ny - 1.0)
        c = min(max(c, 0.0), nx - 1.0)
        i = min(int(r), ny - 2)
        j = min(int(c), nx - 2)
        fr, fc = r - i, c - j
        z00, z01, z10, z11 = z[i, j], z[i, j + 1], z[i + 1, j], z[i + 1, j + 1]
        top = z00 + fc * (z01 - z00)
        bottom = z10 + fc * (z11 - z10)
        out[k] = top + fr * (bottom - top)
        gr[k] = 0.0 if clamp_r else bottom - top
        gc[k] = 0.0 if clamp_c else (1.0 - fr) * (z01 - z00) + fr * (z11 - z10)


@dataclass(frozen=True, eq=False)
class Surface:
    """A height map (m) sampled bilinearly at actual positions (m), with the interpolant's exact gradient.

    ``fixed_rows=True`` (the trace reference): row ``k`` is line ``k``; callers pass the line index
    as ``y`` and the slow-axis gradient is zero (no information along y).
    """

    hmap: HeightMap
    fixed_rows: bool = False

    def sample(self, x, y, *, gradient: bool = True):
        """Heights (m) at positions ``x, y`` (m) and, with ``gradient``, ∂z/∂x and ∂z/∂y (m/m)."""
        dx, dy = self.hmap.pixel_size
        cols = (np.asarray(x, dtype=np.float64) - self.hmap.origin[0]) / dx
        rows = np.asarray(y, dtype=np.float64) if self.fixed_rows else (np.asarray(y) - self.hmap.origin[1]) / dy
        s, gr, gc = np.empty(cols.size), np.empty(cols.size), np.empty(cols.size)
        _bilinear(self.hmap.z, np.ascontiguousarray(rows), np.ascontiguousarray(cols), s, gr, gc)
        if not gradient:
            return s, None, None
        return s, gc / dx, (np.zeros_like(gr) if self.fixed_rows else gr / dy)

    def smoothed(self, sigma_m: float) -> "Surface":
        """The same surface blurred by a Gaussian of σ = ``sigma_m`` (m) along x (and y unless rows are fixed)."""
        dx, dy = self.hmap.pixel_size
        sig = (0.0 if self.fixed_rows else sigma_m / dy, sigma_m / dx)
        return Surface(self.hmap.with_z(ndimage.gaussian_filter(self.hmap.z, sig, mode="nearest")), self.fixed_rows)


def parabolic_dilation(hmap: HeightMap, radius_m: float) -> HeightMap:
    """Grey-scale dilation of ``hmap`` by a paraboloid tip ``(x² + y²)/(2·radius_m)`` (m)."""
    if radius_m <= 0:
        return hmap
    z = hmap.z
    span = float(np.ptp(z))
    out = z
    for axis, step in ((1, hmap.pixel_size[0]), (0, hmap.pixel_size[1])):
        reach = int(np.floor(np.sqrt(2.0 * radius_m * span) / step + 1e-9)) if span > 0 else 0
        if reach == 0:
            continue
        offsets = step * np.arange(-reach, reach + 1)
        profile = -(offsets**2) / (2.0 * radius_m)
        shape = (1, profile.size) if axis == 1 else (profile.size, 1)
        out = ndimage.grey_dilation(out, structure=profile.reshape(shape), footprint=np.ones(shape, bool),
                                    mode="nearest")
    return hmap.with_z(out)


def scenario_reference(scenario, geometry) -> tuple[HeightMap, HeightMap | None, dict]:
    """The scenario's sample and the surface its tip traces, on the simulation grid (stage coordinates, m).

    Returns ``(traced, sample, tip)``: ``traced`` = sample dilated by the scenario's tip; ``sample`` is
    the undilated sample when the tip is a paraboloid (the ``tip`` candidate then re-dilates it with
    the total radius, P_R0 ⊕ P_ΔR = P_(R0+ΔR)), else None (the candidate dilates ``traced`` by P_ΔR);
    ``tip`` describes the known tip (shape, apex radius in m, half-angle in degrees).
    """
    from afmsim.experiment import build_sample
    from afmsim.tip import dilate, mlct_tip

    truth, _mesh = build_sample(scenario, geometry)
    t = scenario.tip
    info = {"shape": t.shape, "apex_radius_m": t.apex_radius_nm * 1e-9, "half_angle_deg": t.half_angle_deg}
    if t.shape == "paraboloid":
        return parabolic_dilation(truth, info["apex_radius_m"]), truth, info
    return dilate(truth, mlct_tip(t.shape, info["apex_radius_m"], t.half_angle_deg)), None, info


def trace_reference(trace: np.ndarray, pixel_size_x: float, origin_x: float) -> Surface:
    """The measured trace (lines × pixels, m) as its own reference: row k = line k, pixel centres at intended x."""
    return Surface(HeightMap(trace, (pixel_size_x, 1.0), (origin_x, 0.0)), fixed_rows=True)
