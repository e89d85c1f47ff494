"""Tests for afmsim.metrics: NSL2 (paper eq. 8–9), registration, lens centres, grating pitch."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.optimize import brentq

from afmsim.metrics import (
    binarize, e_D, image_shift, image_shift_px, lens_centres, left_right_pitch, line_pitches,
    match_centres, nsl2, nsl2_binarized, summarize,
)

DX, DY = 20e-9, 40e-9  # deliberately different, so x/y mix-ups fail

# Paper Table 3 (micro-lenses), 10 experiments.
D_S_T3 = [2011, 2674, 2481, 2570, 2563, 1908, 1924, 2543, 2679, 1868]
D_A_T3 = [1136, 1042, 1096, 1336, 1539, 1399, 1308, 1106, 1318, 1649]


# ---------------------------------------------------------------- synthetic images (pixel units)
def texture(sx=0.0, sy=0.0, shape=(128, 128), seed=1):
    """Smooth random texture sampled at (x − sx, y − sy): a genuine resampling, not a roll."""
    rng = np.random.default_rng(seed)
    k = 40
    kx, ky = rng.normal(0, 0.06, k), rng.normal(0, 0.06, k)
    ph, a = rng.uniform(0, 2 * np.pi, k), rng.normal(size=k)
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    x, y = x - sx, y - sy
    return 1e-7 * sum(a[i] * np.cos(2 * np.pi * (kx[i] * x + ky[i] * y) + ph[i]) for i in range(k))


def caps(centres, radius=10.0, curvature_radius=25.0, shape=(128, 128)):
    """Spherical caps of footprint ``radius`` (px) centred at ``centres`` [(x, y), ...] (px)."""
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    z = np.zeros(shape)
    base = np.sqrt(curvature_radius**2 - radius**2)
    for cx, cy in centres:
        r2 = (x - cx) ** 2 + (y - cy) ** 2
        z += np.clip(np.sqrt(np.clip(curvature_radius**2 - r2, 0, None)) - base, 0, None)
    return z * 1e-8


# ---------------------------------------------------------------- NSL2
def test_nsl2_identical_is_zero():
    img = texture()
    assert nsl2(img, img) == pytest.approx(0.0, abs=1e-9)
    assert nsl2_binarized(img, img) == 0.0


def test_nsl2_negative_is_4n():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(30, 40))
    z = (z - z.mean()) / z.std()
    assert nsl2(z, -z) == pytest.approx(4 * z.size, rel=1e-12)


def test_nsl2_matches_pearson_independently():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(25, 33))
    y = 0.6 * x + rng.normal(size=x.shape) + 5.0
    r = np.corrcoef(x.ravel(), y.ravel())[0, 1]
    assert nsl2(x, y) == pytest.approx(2 * x.size * (1 - r), rel=1e-10)
    # population σ, not sample σ: explicit formula of eq. (8)
    zx = (x - x.mean()) / np.sqrt(np.mean((x - x.mean()) ** 2))
    zy = (y - y.mean()) / np.sqrt(np.mean((y - y.mean()) ** 2))
    assert nsl2(x, y) == pytest.approx(np.sum((zx - zy) ** 2), rel=1e-12)


def test_nsl2_binarized_is_phi_coefficient():
    t, r = texture(), texture(1.5, -0.5)
    bt, br = binarize(t), binarize(r)
    phi = np.corrcoef(bt.ravel(), br.ravel())[0, 1]
    assert nsl2_binarized(t, r) == pytest.approx(2 * t.size * (1 - phi), rel=1e-10)
    assert nsl2_binarized(t, r) > 0


def test_binarize_threshold_is_mean():
    img = np.array([[0.0, 1.0], [2.0, 10.0]])  # mean 3.25
    np.testing.assert_array_equal(binarize(img), [[0, 0], [0, 1]])
    assert binarize(img).dtype == np.float64


def test_nsl2_constant_image_raises_and_names_it():
    z = texture()
    with pytest.raises(ValueError, match="y"):
        nsl2(z, np.full(z.shape, 0.1))
    with pytest.raises(ValueError, match="x"):
        nsl2(np.full(z.shape, 3e-7), z)
    with pytest.raises(ValueError, match="retrace"):
        nsl2_binarized(z, np.zeros(z.shape))
    with pytest.raises(ValueError, match="trace"):
        nsl2_binarized(np.ones(z.shape), z)


def test_nsl2_shape_mismatch_raises():
    with pytest.raises(ValueError, match="shape"):
        nsl2(np.ones((3, 4)) * np.arange(4), np.ones((4, 3)) * np.arange(3))
    with pytest.raises(ValueError, match="shape"):
        nsl2_binarized(texture(shape=(20, 30)), texture(shape=(30, 20)))


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 10_000), st.floats(-0.99, 0.99), st.floats(1e-9, 1e3))
def test_nsl2_bounds_and_affine_invariance(seed, rho, scale):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=200)
    y = rho * x + np.sqrt(1 - rho**2) * rng.normal(size=200)
    d = nsl2(x, y)
    assert -1e-9 <= d <= 4 * x.size + 1e-9
    assert nsl2(scale * x + 7.0, y) == pytest.approx(d, rel=1e-7, abs=1e-7)


def test_e_D_paper_table3():
    assert e_D(2011, 1136) == pytest.approx(0.435, abs=5e-4)  # row 1: 43.5 %
    per = e_D(D_S_T3, D_A_T3)
    assert per.shape == (10,)
    # the paper's "Mean" E_D (44.3 %) is e_D of the mean D values
    assert e_D(np.mean(D_S_T3), np.mean(D_A_T3)) == pytest.approx(0.443, abs=5e-4)
    with pytest.raises(ValueError):
        e_D(0.0, 1.0)


def test_summarize_uses_sample_std_like_paper():
    s = summarize(D_A_T3)
    assert s["mean"] == pytest.approx(1292.9)
    assert s["std"] == pytest.approx(200.7, abs=0.05)  # Table 3 σ of D_A
    assert s["per_experiment"] == [float(v) for v in D_A_T3]
    assert np.isnan(summarize([3.0])["std"])
    with pytest.raises(ValueError):
        summarize([])


# ---------------------------------------------------------------- registration
def test_shift_sign_convention_pinned():
    # retrace = trace moved to +x by 3 px  →  shift_x = +3·dx, shift_y = 0
    sx, sy = image_shift(texture(), texture(3.0, 0.0), (DX, DY))
    assert sx == pytest.approx(3 * DX, abs=0.05 * DX)
    assert sy == pytest.approx(0.0, abs=0.05 * DY)
    # and +y by 2 lines  →  shift_y = +2·dy
    sx, sy = image_shift(texture(), texture(0.0, 2.0), (DX, DY))
    assert sx == pytest.approx(0.0, abs=0.05 * DX)
    assert sy == pytest.approx(2 * DY, abs=0.05 * DY)


@pytest.mark.parametrize("s", [(3.0, 0.0), (-2.0, 5.0), (0.37, -1.21), (-2.5, 0.25), (7.3, 4.6)])
def test_shift_texture_recovered(s):
    sx, sy = image_shift_px(texture(), texture(*s))
    assert sx == pytest.approx(s[0], abs=0.05)
    assert sy == pytest.approx(s[1], abs=0.05)


@pytest.mark.parametrize("s", [(4.0, -1.0), (0.37, -1.21), (-2.5, 0.25), (1.8, 3.35)])
def test_shift_lens_recovered(s):
    c = [(60.3, 64.1)]
    t = caps(c, radius=25, curvature_radius=60)
    r = caps([(c[0][0] + s[0], c[0][1] + s[1])], radius=25, curvature_radius=60)
    sx, sy = image_shift(t, r, DX)
    assert sx / DX == pytest.approx(s[0], abs=0.05)
    assert sy / DX == pytest.approx(s[1], abs=0.05)


def test_shift_constant_image_raises():
    with pytest.raises(ValueError, match="retrace"):
        image_shift(texture(), np.zeros((128, 128)), DX)


# ---------------------------------------------------------------- lens centres
def test_lens_centres_known_positions():
    true_px = [(20.3, 25.7), (64.0, 30.25), (100.8, 22.1), (40.45, 90.6), (95.1, 95.9)]
    img = caps(true_px)
    got = lens_centres(img, (DX, DY), origin=(1e-6, -2e-6))
    assert got.shape == (5, 2)
    want = np.array([(1e-6 + x * DX, -2e-6 + y * DY) for x, y in true_px])
    ia, ib, disp = match_centres(want, got)
    assert len(ia) == 5
    assert np.all(np.abs(disp[:, 0]) < 0.1 * DX)
    assert np.all(np.abs(disp[:, 1]) < 0.1 * DY)
    assert np.all(np.diff(got[:, 1]) >= 0)  # sorted by y


def test_lens_centres_drops_border_lenses_and_flat_image():
    img = caps([(64.2, 64.7), (3.0, 60.0)])  # second one cut by the left border
    got = lens_centres(img, DX)
    assert got.shape == (1, 2)
    assert got[0] / DX == pytest.approx([64.2, 64.7], abs=0.1)
    assert lens_centres(img, DX, exclude_border=False).shape == (2, 2)
    assert lens_centres(np.zeros((32, 32)), DX).shape == (0, 2)


# ---------------------------------------------------------------- grating
P_TRUE = 5e-6            # grating period (m)
FIELD = 30e-6            # nominal scan length (m)
NX = 600


def _stage_position(x, k):
    """True sample position for nominal x: slope (1 − k) on the left rising to (1 + k) on the
    right, so features look stretched (wider) on the left and compressed on the right."""
    return x + k * (x - FIELD / 2) ** 2 / FIELD


def _grating_image(k, ny=16, edge=0.03):
    dx = FIELD / NX
    x = np.arange(NX) * dx
    u = _stage_position(x, k) + 0.7e-6  # arbitrary phase
    # smoothed rectangle wave, 50 % duty: rising edges at u = m·P, falling at u = (m + ½)·P
    h = 0.5 * (np.tanh(np.sin(2 * np.pi * u / P_TRUE) / edge) + 1)
    return np.tile(500e-9 * h, (ny, 1)), dx


def _expected_left_right(k):
    """Independent reference: invert the stage map at every rising edge (u = mP) by root-finding."""
    dx = FIELD / NX
    x_end = (NX - 1) * dx
    f = lambda x, m: _stage_position(x, k) + 0.7e-6 - m * P_TRUE
    edges = []
    for m in range(-2, 12):
        if f(0, m) < 0 < f(x_end, m):
            edges.append(brentq(f, 0, x_end, args=(m,), xtol=1e-15))
    edges = np.asarray(edges)
    per, mid = np.diff(edges), 0.5 * (edges[1:] + edges[:-1])
    return per[mid < x_end / 2].mean(), per[mid >= x_end / 2].mean(), edges


def test_grating_uniform_period_and_width():
    img, dx = _grating_image(k=0.0)
    g = line_pitches(img, dx)
    assert np.allclose(g.pitches_m, P_TRUE, atol=0.05 * dx)
    assert np.allclose(g.widths_m, 0.5 * P_TRUE, atol=0.1 * dx)
    left, right = left_right_pitch(img, dx)
    assert left == pytest.approx(P_TRUE, abs=0.05 * dx)
    assert right == pytest.approx(P_TRUE, abs=0.05 * dx)


def test_grating_left_wider_than_right_recovered():
    k = 0.12
    img, dx = _grating_image(k)
    left, right = left_right_pitch(img, dx)
    want_l, want_r, edges = _expected_left_right(k)
    assert left > right
    assert left == pytest.approx(want_l, abs=0.1 * dx)
    assert right == pytest.approx(want_r, abs=0.1 * dx)
    g = line_pitches(img, dx)
    np.testing.assert_allclose(g.rising_m, edges, atol=0.1 * dx)
    # widths also shrink left → right
    wl, wr = left_right_pitch(img, dx, quantity="width")
    assert wl > wr
    # mirrored (retrace-like) distortion swaps the sides
    img_m = img[:, ::-1]
    lm, rm = left_right_pitch(img_m, dx)
    assert lm < rm


def test_grating_noise_robust_edges():
    rng = np.random.default_rng(5)
    img, dx = _grating_image(k=0.0)
    noisy = img + rng.normal(0, 30e-9, img.shape)
    g = line_pitches(noisy, dx)
    assert np.allclose(g.pitches_m, P_TRUE, atol=0.3 * dx)
    with pytest.raises(ValueError, match="flat"):
        line_pitches(np.zeros((4, 50)), dx)
