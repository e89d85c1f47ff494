"""Gwyddion .gwy export/import round trip."""

import os

import gwyfile
import numpy as np
import pytest

from afmsim.report import read_gwy, write_gwy
from afmsim.samples.heightmap import HeightMap


def _maps():
    rng = np.random.default_rng(7)
    a = HeightMap(rng.normal(0, 3e-9, (12, 20)), pixel_size=(25e-9, 40e-9), origin=(1.5e-6, -2e-7))
    b = HeightMap(rng.normal(0, 1e-9, (12, 20)), pixel_size=(25e-9, 40e-9), origin=(1.5e-6, -2e-7))
    c = HeightMap(rng.normal(5e-9, 1e-9, (7, 5)), pixel_size=(1e-6 / 3, 7e-9), origin=(0.0, 0.0))
    return {"trace none": a, "retrace diapi": b, "topography": c}


def test_round_trip_data_geometry_titles(tmp_path):
    maps = _maps()
    path = write_gwy(tmp_path / "scan.gwy", maps)
    assert path == tmp_path / "scan.gwy"
    back = read_gwy(path)
    assert list(back) == list(maps)  # titles, in order
    for title, m in maps.items():
        r = back[title]
        assert r.shape == m.shape
        np.testing.assert_array_equal(r.z, m.z)
        np.testing.assert_allclose(r.pixel_size, m.pixel_size, rtol=1e-15, atol=0)
        np.testing.assert_allclose(r.origin, m.origin, rtol=1e-15, atol=1e-15 * max(m.pixel_size))
        np.testing.assert_allclose(r.size, m.size, rtol=1e-15)
    # no temporary files left beside the output
    assert sorted(os.listdir(tmp_path)) == ["scan.gwy"]


def test_file_content_as_gwyddion_sees_it(tmp_path):
    maps = _maps()
    write_gwy(tmp_path / "scan.gwy", maps)
    obj = gwyfile.load(str(tmp_path / "scan.gwy"))
    fields = gwyfile.util.get_datafields(obj)
    assert set(fields) == set(maps)
    for title, m in maps.items():
        f = fields[title]
        assert f.si_unit_xy.unitstr == "m"
        assert f.si_unit_z.unitstr == "m"
        ny, nx = m.shape
        assert (f["xres"], f["yres"]) == (nx, ny)
        assert f.xreal == pytest.approx(nx * m.pixel_size[0], rel=1e-15)
        assert f.yreal == pytest.approx(ny * m.pixel_size[1], rel=1e-15)
        # Gwyddion's offset is the top-left pixel *corner*; HeightMap.origin is its centre
        assert f.xoff == pytest.approx(m.origin[0] - m.pixel_size[0] / 2, rel=1e-15, abs=1e-24)
        assert f.yoff == pytest.approx(m.origin[1] - m.pixel_size[1] / 2, rel=1e-15, abs=1e-24)
        np.testing.assert_array_equal(f.data, m.z)


def test_geometry_read_without_afmsim_metadata(tmp_path):
    """A file whose metadata is missing (e.g. re-saved by another tool) reads from xreal/xoff."""
    m = _maps()["trace none"]
    write_gwy(tmp_path / "a.gwy", {"t": m})
    obj = gwyfile.load(str(tmp_path / "a.gwy"))
    del obj["/0/meta"]
    obj.tofile(str(tmp_path / "b.gwy"))
    r = read_gwy(tmp_path / "b.gwy")["t"]
    np.testing.assert_allclose(r.pixel_size, m.pixel_size, rtol=1e-14)
    np.testing.assert_allclose(r.origin, m.origin, rtol=1e-14, atol=1e-14 * m.pixel_size[0])


def test_overwrite_is_atomic_and_single_char_title(tmp_path):
    p = tmp_path / "x.gwy"
    m = _maps()["topography"]
    write_gwy(p, {"first": m})
    write_gwy(p, {"z": m.with_z(2 * m.z)})  # 1-char title must still be stored as a string
    back = read_gwy(p)
    assert list(back) == ["z"]
    np.testing.assert_array_equal(back["z"].z, 2 * m.z)
    assert sorted(os.listdir(tmp_path)) == ["x.gwy"]


def test_bad_input(tmp_path):
    with pytest.raises(ValueError):
        write_gwy(tmp_path / "e.gwy", {})
    with pytest.raises(TypeError):
        write_gwy(tmp_path / "e.gwy", {"a": np.zeros((3, 3))})
    assert not (tmp_path / "e.gwy").exists()
