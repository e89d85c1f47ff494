"""Samples: micro-lens mesh + ray casting, HS-500MG grating, loaders."""

import os

import numpy as np
import pytest
import trimesh

from afmsim.samples import (
    DEFAULT_MESH_PATH,
    HeightMap,
    MicroLensArray,
    grating_heightmap,
    load_default_mesh,
    load_heightmap,
    load_mesh,
    mesh_file_to_heightmap,
    mesh_to_heightmap,
    regenerate_default_mesh,
    sample_from_spec,
    save_heightmap,
    save_mesh,
)

# a coarser lens than the default keeps the tests fast and the faceting error visible
SMALL = dict(diameter=4e-6, sag=0.8e-6, pitch=5e-6, n_lenses=(2, 2), edge_length=200e-9)


# ---------------------------------------------------------------- micro-lens mesh
@pytest.mark.parametrize("arrangement", ["square", "hexagonal"])
def test_microlens_mesh_is_watertight_volume(arrangement):
    lens = MicroLensArray(arrangement=arrangement, **SMALL)
    m = lens.mesh()
    assert m.is_watertight and m.is_winding_consistent and m.is_volume
    # volume = slab + caps: V_cap = π s² (3R − s)/3
    x0, y0, x1, y1 = lens.slab_bounds()
    R, s = lens.radius_of_curvature, lens.sag
    v_ref = (x1 - x0) * (y1 - y0) * lens.base_thickness + 4 * np.pi * s * s * (3 * R - s) / 3
    assert m.volume == pytest.approx(v_ref, rel=2e-3)  # inscribed facets lose a little volume


def test_touching_lenses_still_watertight():
    m = MicroLensArray(diameter=4e-6, sag=0.5e-6, pitch=4e-6, n_lenses=(2, 2), edge_length=250e-9).mesh()
    assert m.is_watertight and m.is_volume


@pytest.mark.parametrize("arrangement", ["square", "hexagonal"])
def test_raycast_matches_spherical_cap(arrangement):
    lens = MicroLensArray(arrangement=arrangement, **SMALL)
    m = lens.mesh()
    tol = lens.max_facet_error(m)
    # bound ties to the mesh resolution: ~r²/(2R) with r ≈ edge/√3
    assert tol < 3 * SMALL["edge_length"] ** 2 / (2 * lens.radius_of_curvature)
    hm = lens.heightmap((101, 117), extent=(11e-6, 10e-6), center=(0.13e-6, -0.07e-6), mesh=m)
    X, Y = np.meshgrid(hm.x, hm.y)
    ref = lens.height(X, Y)
    err = hm.z - ref
    assert np.abs(err).max() <= tol * 1.001 + 1e-13
    assert err.max() <= 1e-13  # inscribed facets: never above the sphere
    # explicit cap formula at lens centres and flat far away
    R, s, a = lens.radius_of_curvature, lens.sag, lens.diameter / 2
    rho = np.sqrt(np.min([(X - cx) ** 2 + (Y - cy) ** 2 for cx, cy in lens.lens_centers()], axis=0))
    cap = np.where(rho < a, np.sqrt(np.maximum(R * R - rho * rho, 0)) - (R - s), 0.0)
    np.testing.assert_allclose(hm.z, cap, atol=tol * 1.001 + 1e-13, rtol=0)
    assert np.abs(hm.z[rho > a + 1e-9]).max() < 1e-18  # flat top at z = 0 (float rounding only)


def test_raycast_engines_agree():
    m = MicroLensArray(**SMALL).mesh()
    a = mesh_to_heightmap(m, (24, 28), engine="trimesh")
    b = mesh_to_heightmap(m, (24, 28), engine="vertical")
    np.testing.assert_allclose(a.z, b.z, atol=1e-15, rtol=0)
    with pytest.raises(ValueError, match="engine"):
        mesh_to_heightmap(m, (8, 8), engine="nope")


def test_raycast_background_and_grid():
    m = MicroLensArray(**SMALL).mesh()
    hm = mesh_to_heightmap(m, (16, 16), pixel_size=(2e-6, 2e-6), center=(0, 0), background=-5e-6)
    assert hm.pixel_size == (2e-6, 2e-6)
    assert hm.x.mean() == pytest.approx(0, abs=1e-15)
    assert hm.z[0, 0] == -5e-6  # corner ray (x = −15 µm) misses the 11 µm slab


def test_raycast_512_reaches_the_lens_apex():
    lens = MicroLensArray()
    hm = lens.heightmap((512, 512), mesh=lens.mesh())
    assert hm.z.max() == pytest.approx(lens.sag, abs=2e-9)


def test_default_mesh_file(tmp_path):
    assert os.path.getsize(DEFAULT_MESH_PATH) < 1_000_000
    m = load_default_mesh()
    assert m.is_watertight and m.is_volume
    lens = MicroLensArray()
    np.testing.assert_allclose(m.bounds[1, :2], lens.slab_bounds()[2:], rtol=1e-6)
    p = regenerate_default_mesh(str(tmp_path / "lens.ply"))
    m2 = load_mesh(p)
    np.testing.assert_allclose(np.sort(m2.vertices, axis=0), np.sort(m.vertices, axis=0), atol=1e-12)


def test_microlens_rejects_bad_geometry():
    with pytest.raises(ValueError, match="overlap"):
        MicroLensArray(diameter=6e-6, pitch=5e-6)
    with pytest.raises(ValueError, match="hemisphere"):
        MicroLensArray(diameter=2e-6, sag=1.5e-6)
    with pytest.raises(ValueError, match="arrangement"):
        MicroLensArray(arrangement="triangular")


# ---------------------------------------------------------------- grating
def _crossings(profile, level, x):
    """x positions where the profile crosses ``level`` (linear interpolation), with the sign."""
    d = profile - level
    k = np.nonzero(np.sign(d[:-1]) != np.sign(d[1:]))[0]
    xc = x[k] + (x[k + 1] - x[k]) * d[k] / (d[k] - d[k + 1])
    return xc, np.sign(d[k + 1] - d[k])


@pytest.mark.parametrize("duty,angle", [(0.5, 90.0), (0.5, 80.0), (0.3, 60.0)])
def test_grating_height_period_duty(duty, angle):
    hm = grating_heightmap((64, 1000), extent=(40e-6, 4e-6), duty_cycle=duty, sidewall_angle_deg=angle,
                           phase=(0.37e-6, 0))
    z = hm.z
    # lines run along y: every row identical, z varies along x (fast scan crosses the lines)
    assert np.all(z == z[0])
    prof = z[0]
    top, bottom = np.percentile(prof, 95), np.percentile(prof, 5)
    assert top - bottom == pytest.approx(500e-9, rel=1e-9)
    xc, sgn = _crossings(prof, 250e-9, hm.x)
    rises, falls = xc[sgn > 0], xc[sgn < 0]
    period = np.diff(rises).mean()
    assert period == pytest.approx(5e-6, abs=0.01 * hm.pixel_size[0])
    first_fall = falls[falls > rises[0]][0]
    assert (first_fall - rises[0]) / period == pytest.approx(duty, abs=0.5 * hm.pixel_size[0] / 5e-6)
    assert (prof > 250e-9).mean() == pytest.approx(duty, abs=2 * 8 / 1000)  # 8 edges, ±1 px each
    # sidewall: 10–90 % rise width = 0.8·h/tan(angle) (box filter blurs by ≤ 1 px, interpolation by ≤ 0.6 px)
    w = 0.0 if angle == 90 else 500e-9 / np.tan(np.radians(angle))
    r10 = _crossings(prof, 50e-9, hm.x)[0]
    r90 = _crossings(prof, 450e-9, hm.x)[0]
    width = np.abs(r90[:4] - r10[:4]).mean()
    assert width == pytest.approx(0.8 * w, abs=1.7 * hm.pixel_size[0])  # box filter + linear interp.


def test_grating_mean_is_exact_duty_for_vertical_walls():
    hm = grating_heightmap((4, 500), extent=(50e-6, 1e-6), duty_cycle=0.4, sidewall_angle_deg=90, phase=(0.123e-6, 0))
    assert hm.z.mean() == pytest.approx(0.4 * 500e-9, rel=1e-9)  # box-filtered, whole periods


def test_grating_variants_and_errors():
    g = grating_heightmap((32, 32), lines_along="x")
    assert np.all(g.z.T == g.z.T[0])
    for pattern in ("squares", "pillars", "holes"):
        g = grating_heightmap((64, 64), pattern=pattern)
        assert g.z.min() >= 0 and g.z.max() == pytest.approx(500e-9)
    with pytest.raises(ValueError, match="sidewalls too shallow"):
        grating_heightmap((8, 8), duty_cycle=0.5, sidewall_angle_deg=10)
    with pytest.raises(ValueError, match="duty_cycle"):
        grating_heightmap((8, 8), duty_cycle=1.2)
    with pytest.raises(ValueError, match="pattern"):
        grating_heightmap((8, 8), pattern="zigzag")


# ---------------------------------------------------------------- loaders
def _hm():
    rng = np.random.default_rng(1)
    return HeightMap(rng.normal(0, 1e-7, (12, 17)), (3e-8, 4e-8), (1e-6, -2e-6))


@pytest.mark.parametrize("suffix", [".npy", ".tiff", ".tif"])
def test_heightmap_roundtrip(tmp_path, suffix):
    hm = _hm()
    p = save_heightmap(hm, tmp_path / f"map{suffix}", z_scale=1e-9)  # stored in nm
    back = load_heightmap(p, hm.pixel_size, origin=hm.origin, z_scale=1e-9)
    np.testing.assert_allclose(back.z, hm.z, rtol=1e-12, atol=0)
    assert back.pixel_size == hm.pixel_size and back.origin == hm.origin
    assert sample_from_spec("heightmap", path=p, pixel_size=3e-8, z_scale=1e-9).shape == hm.shape


def test_heightmap_loader_rejects_bad_input(tmp_path):
    import tifffile

    with pytest.raises(ValueError, match="no such file"):
        load_heightmap(tmp_path / "missing.npy", 1e-8)
    np.save(tmp_path / "cube.npy", np.zeros((3, 4, 5)))
    with pytest.raises(ValueError, match="2-D"):
        load_heightmap(tmp_path / "cube.npy", 1e-8)
    np.save(tmp_path / "line.npy", np.zeros(10))
    with pytest.raises(ValueError, match="2-D"):
        load_heightmap(tmp_path / "line.npy", 1e-8)
    bad = np.zeros((4, 4)); bad[1, 1] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    with pytest.raises(ValueError, match="NaN"):
        load_heightmap(tmp_path / "nan.npy", 1e-8)
    np.save(tmp_path / "str.npy", np.array([["a", "b"], ["c", "d"]]))
    with pytest.raises(ValueError, match="real numbers"):
        load_heightmap(tmp_path / "str.npy", 1e-8)
    tifffile.imwrite(tmp_path / "rgb.tiff", np.zeros((8, 8, 3), np.uint8), photometric="rgb")
    with pytest.raises(ValueError, match="RGB"):
        load_heightmap(tmp_path / "rgb.tiff", 1e-8)
    (tmp_path / "junk.tiff").write_bytes(b"not a tiff at all")
    with pytest.raises(ValueError, match="junk.tiff"):
        load_heightmap(tmp_path / "junk.tiff", 1e-8)
    (tmp_path / "junk.npy").write_bytes(b"nope")
    with pytest.raises(ValueError, match="junk.npy"):
        load_heightmap(tmp_path / "junk.npy", 1e-8)
    np.save(tmp_path / "ok.npy", np.zeros((4, 4)))
    with pytest.raises(ValueError, match="pixel_size"):
        load_heightmap(tmp_path / "ok.npy", 0.0)
    (tmp_path / "map.csv").write_text("1,2\n3,4\n")
    with pytest.raises(ValueError, match="suffix"):
        load_heightmap(tmp_path / "map.csv", 1e-8)


@pytest.mark.parametrize("suffix", [".stl", ".obj", ".ply"])
def test_mesh_roundtrip(tmp_path, suffix):
    lens = MicroLensArray(**SMALL)
    m = lens.mesh()
    p = save_mesh(m, tmp_path / f"lens{suffix}", unit=1e-6)
    back = load_mesh(p, unit=1e-6)
    assert back.is_watertight
    np.testing.assert_allclose(back.bounds, m.bounds, atol=1e-12)
    a = mesh_to_heightmap(m, (40, 40))
    b = mesh_file_to_heightmap(p, (40, 40), unit=1e-6)
    np.testing.assert_allclose(b.z, a.z, atol=1e-12)  # STL stores float32 µm: ~1e-13 m rounding
    c = sample_from_spec("mesh", shape=(40, 40), extent=None, path=p, unit=1e-6)
    np.testing.assert_allclose(c.z, a.z, atol=1e-12)


def test_mesh_loader_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="no such file"):
        load_mesh(tmp_path / "nothing.stl")
    (tmp_path / "junk.stl").write_bytes(b"solid junk\nthis is not an stl\n")
    with pytest.raises(ValueError, match="junk.stl"):
        load_mesh(tmp_path / "junk.stl")
    (tmp_path / "empty.obj").write_text("# nothing\n")
    with pytest.raises(ValueError, match="empty.obj"):
        load_mesh(tmp_path / "empty.obj")
    with pytest.raises(ValueError, match="unit"):
        load_mesh(DEFAULT_MESH_PATH, unit=0)
    with pytest.raises(ValueError, match="non-empty"):
        mesh_to_heightmap(trimesh.Trimesh(), (4, 4))


def test_sample_from_spec_kinds():
    a = sample_from_spec("microlens", (64, 64), (12e-6, 12e-6), **SMALL)
    assert a.shape == (64, 64) and a.z.max() == pytest.approx(0.8e-6, abs=5e-9)
    g = sample_from_spec("grating", (32, 64), (10e-6, 5e-6), duty_cycle=0.5)
    assert g.size == pytest.approx((10e-6, 5e-6))
    with pytest.raises(ValueError, match="kind"):
        sample_from_spec("moon")
    with pytest.raises(ValueError, match="micro-lens parameter"):
        sample_from_spec("microlens", radius=1)
    with pytest.raises(ValueError, match="path"):
        sample_from_spec("mesh")
