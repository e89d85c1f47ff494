"""Tip shapes and tip–sample dilation (Villarrubia) against analytic profiles."""


import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from afmsim.samples import HeightMap, MicroLensArray, grating_heightmap
from afmsim.tip import (
    ArrayTip,
    ConeTip,
    ParabolicTip,
    dilate,
    erode,
    mlct_tip,
    sampling_info,
    structure_element,
    tip_array,
)


def _grid(n, dx, dy=None):
    dy = dx if dy is None else dy
    return np.meshgrid(dx * (np.arange(n) - n // 2), dy * (np.arange(n) - n // 2))


# ---------------------------------------------------------------- shapes
def test_mlct_defaults_and_cone_geometry():
    tip = mlct_tip()
    assert isinstance(tip, ConeTip) and tip.apex_radius == 20e-9 and 17.5 <= tip.half_angle_deg <= 25
    R, a = tip.apex_radius, np.radians(tip.half_angle_deg)
    rt = R * np.cos(a)
    r = np.array([0.0, rt * (1 - 1e-9), rt * (1 + 1e-9), 1e-6])
    t = tip.height(r, 0 * r)
    assert t[0] == 0
    assert t[1] == pytest.approx(t[2], abs=1e-15)  # continuous at the sphere–cone junction
    # far away: cone slope 1/tan(α); slope continuous at the junction (C¹)
    assert (tip.height(2e-6, 0) - tip.height(1e-6, 0)) / 1e-6 == pytest.approx(1 / np.tan(a))
    eps = 1e-13
    slope_in = (tip.height(rt - eps, 0) - tip.height(rt - 2 * eps, 0)) / eps
    assert slope_in == pytest.approx(1 / np.tan(a), rel=1e-3)
    for h in (1e-9, 5e-9, 100e-9, 2e-6):
        assert tip.height(tip.radius_at_height(h), 0) == pytest.approx(h, rel=1e-9)
    p = ParabolicTip(30e-9)
    assert p.height(30e-9, 40e-9) == pytest.approx((50e-9) ** 2 / 60e-9)
    assert p.height(p.radius_at_height(1e-7), 0) == pytest.approx(1e-7)
    with pytest.raises(ValueError):
        ConeTip(half_angle_deg=95)
    with pytest.raises(ValueError):
        mlct_tip("pyramid")


def test_tip_array_crop_is_exact():
    tip = mlct_tip()
    t, fp = tip_array(tip, (10e-9, 10e-9), 500e-9)
    assert t.shape[0] % 2 == 1 and t[t.shape[0] // 2, t.shape[1] // 2] == 0
    assert t[fp].max() <= 500e-9
    r = tip.radius_at_height(500e-9)  # ≈ h·tan α ≈ 180 nm for 20°
    assert t.shape[1] == 2 * int(r / 10e-9) + 1
    # cropping changes nothing: compare with a much larger footprint
    hm = grating_heightmap((64, 96), extent=(3e-6, 2e-6), sidewall_angle_deg=90, pixel_size=None)
    big_t, _ = tip_array(tip, hm.pixel_size, max_radius=1.0e-6)
    ref = ndimage.grey_dilation(hm.z, structure=-big_t[::-1, ::-1], mode="nearest")
    np.testing.assert_allclose(dilate(hm, tip).z, ref, atol=1e-18, rtol=0)


def test_sampling_info_flags_unresolved_apex():
    info = sampling_info(mlct_tip(), (78e-9, 78e-9), 1e-6)
    assert info["apex_resolved"] is False and info["apex_radius_px"] < 1
    info = sampling_info(mlct_tip(), (5e-9, 5e-9), 1e-6)
    assert info["apex_resolved"] is True and info["apex_radius_px"] == pytest.approx(4)


# ---------------------------------------------------------------- dilation: sign and reflection
def test_dilation_of_a_spike_is_the_reflected_inverted_tip():
    """I(x) = max_v S(x+v) − t(v): a spike at x0 images as S0 − t(x0 − x) (Villarrubia)."""
    dx = 1e-8
    t = np.zeros((3, 5))
    t[1] = [4e-9, 3e-9, 0.0, 1e-9, 2e-9]  # steep on the −x side, shallow on the +x side
    t[0] = t[2] = 5e-9
    tip = ArrayTip(t, (dx, dx))
    z = np.zeros((9, 9))
    z[4, 4] = 10e-9
    im = dilate(HeightMap(z, (dx, dx)), tip).z
    # apex at x0 − d (left of the spike) touches with the tip's +x side: t(+d)
    np.testing.assert_allclose(im[4, 2:7], 10e-9 - np.array([2e-9, 1e-9, 0.0, 3e-9, 4e-9]), atol=1e-24)
    b, _ = structure_element(tip, (dx, dx))
    assert b.max() == 0 and b[1, 1] == -1e-9  # structure = −tip reflected
    with pytest.raises(ValueError, match="sampled at"):
        dilate(HeightMap(z, (2 * dx, dx)), tip)
    with pytest.raises(ValueError, match="odd shape"):
        ArrayTip(np.zeros((2, 3)), (dx, dx))


# ---------------------------------------------------------------- dilation vs analytic profiles
@pytest.mark.parametrize("dx,dy", [(10e-9, 10e-9), (37e-9, 23e-9)])
def test_paraboloid_tip_on_paraboloid_bump(dx, dy):
    """S = max(0, h − r²/2Rs), t = r²/2Rt  ⇒  I = max(0, h − r²/2(Rs+Rt)) exactly (continuous).

    The grid restricts the contact offset to pixel offsets, ≤ half a pixel diagonal from the
    continuous optimum: error ≤ ½(1/Rs + 1/Rt)(dx² + dy²)/4, and never positive."""
    Rs, Rt, h = 400e-9, 60e-9, 300e-9
    n = 129
    X, Y = _grid(n, dx, dy)
    S = np.maximum(0.0, h - (X * X + Y * Y) / (2 * Rs))
    hm = HeightMap(S, (dx, dy), (X[0, 0], Y[0, 0]))
    im = dilate(hm, ParabolicTip(Rt)).z
    ref = np.maximum(0.0, h - (X * X + Y * Y) / (2 * (Rs + Rt)))
    tol = 0.5 * (1 / Rs + 1 / Rt) * (dx * dx + dy * dy) / 4
    inner = (np.abs(X) < X.max() * 0.7) & (np.abs(Y) < Y.max() * 0.7)  # away from the border
    err = (im - ref)[inner]
    assert err.max() <= 1e-18
    assert err.min() >= -tol
    assert np.abs(err).max() > 0 or dx == 10e-9  # the discretisation error is real on the odd grid


@pytest.mark.parametrize("angle", [17.5, 25.0])
def test_cone_tip_on_step_images_the_tip_flank(angle):
    """Step of height H at x_e: for x < x_e the image is H − t(x_e − x) down to the floor;
    the broadened edge is radius_at_height(H) ≈ H·tan α (+ apex term) wide."""
    dx, H = 5e-9, 500e-9
    tip = ConeTip(20e-9, angle)
    nx = 401
    x = dx * np.arange(nx)
    ke = 250
    z = np.where(np.arange(nx) >= ke, H, 0.0)
    hm = HeightMap(np.tile(z, (21, 1)), (dx, dx))
    im = dilate(hm, tip).z[10]
    xe = x[ke]
    ref = np.where(x >= xe, H, np.maximum(0.0, H - tip.height(xe - x, 0.0)))
    np.testing.assert_allclose(im, ref, atol=1e-18, rtol=0)
    width = (im[:ke] > 0).sum() * dx
    assert width == pytest.approx(tip.radius_at_height(H), abs=dx)
    a = np.radians(angle)  # sphere-capped cone: H·tan α plus R(1 − sin α)/cos α from the blunt apex
    assert tip.radius_at_height(H) == pytest.approx(H * np.tan(a) + 20e-9 * (1 - np.sin(a)) / np.cos(a))


def test_cone_tip_on_lens_is_bounded_by_sphere_of_larger_radius():
    """Sphere-on-plane: a cap of radius Rc imaged by a tip whose contact stays on the apex
    sphere (near the top) gives a cap of radius Rc + R_tip (Villarrubia), checked on the lens."""
    lens = MicroLensArray(diameter=4e-6, sag=0.8e-6, pitch=5e-6, n_lenses=(1, 1), edge_length=100e-9)
    n, ext = 201, 1.0e-6  # 5 nm pixels around the apex: contact on the 60 nm apex sphere
    X, Y = _grid(n, ext / n)
    hm = HeightMap(lens.height(X, Y), (ext / n, ext / n), (X[0, 0], Y[0, 0]))
    Rt = 60e-9
    im = dilate(hm, ConeTip(Rt, 20.0)).z
    Rc, s = lens.radius_of_curvature, lens.sag
    rho2 = X * X + Y * Y
    ref = np.sqrt((Rc + Rt) ** 2 - rho2) - (Rc + Rt) + s  # apex height on the grown sphere
    inner = rho2 < (0.4e-6) ** 2
    tol = 0.5 * (1 / Rc + 1 / Rt) * 2 * (ext / n) ** 2 / 4 + 1e-12  # + lens-height rounding
    err = (im - ref)[inner]
    assert err.max() <= 1e-15 and err.min() >= -tol


# ---------------------------------------------------------------- properties and speed
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), angle=st.floats(10, 40), R=st.floats(5e-9, 100e-9))
def test_dilation_properties(seed, angle, R):
    rng = np.random.default_rng(seed)
    z = ndimage.gaussian_filter(rng.normal(0, 50e-9, (40, 40)), 2)
    hm = HeightMap(z, (20e-9, 20e-9))
    tip = ConeTip(R, angle)
    im = dilate(hm, tip).z
    assert np.all(im >= z)  # the apex never goes below the surface
    assert np.all(dilate(hm.with_z(z + 1e-7), tip).z == pytest.approx(im + 1e-7, abs=1e-18))
    rec = erode(hm.with_z(im), tip).z
    assert np.all(rec >= z - 1e-18)  # reconstruction is an upper bound of the true surface
    assert np.all(rec <= im + 1e-18)


def test_dilation_of_real_samples_with_mlct_lies_on_or_above_them():
    lens = MicroLensArray()
    for hm in (lens.heightmap((256, 256), (5e-6, 5e-6)),
               grating_heightmap((256, 256), (5e-6, 5e-6), sidewall_angle_deg=90)):
        im = dilate(hm, mlct_tip())
        assert np.all(im.z >= hm.z)
