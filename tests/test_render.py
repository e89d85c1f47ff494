"""Off-screen 3D views (pyvista/VTK on EGL). Rendering tests skip only where rendering is impossible."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import matplotlib
import numpy as np
import pytest

from afmsim.render import (
    RenderingUnavailable,
    render_height_map,
    render_mesh,
    rendering_available,
    z_exaggeration_for,
)
from afmsim.samples.heightmap import HeightMap

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def can_render():
    ok, reason = rendering_available()
    if not ok:
        pytest.skip(f"off-screen rendering impossible here: {reason}")
    return reason


def _bump(n=64, height=20e-9, size=2e-6):
    x = np.linspace(-1, 1, n)
    xx, yy = np.meshgrid(x, x)
    z = height * np.exp(-(xx**2 + yy**2) / 0.15)
    return HeightMap(z, pixel_size=(size / n, size / n), origin=(0.0, 0.0))


def _read_png(path):
    img = matplotlib.image.imread(str(path))  # float in [0, 1], (h, w, 3|4)
    return np.round(img[..., :3] * 255).astype(int)


def _near(img, rgb01, tol=40):
    return np.abs(img - np.asarray(rgb01[:3]) * 255).max(axis=2) <= tol


def test_height_map_png_is_a_real_picture(tmp_path, can_render):
    path = render_height_map(_bump(), tmp_path / "bump_render.png", title="gaussian bump")
    assert path.exists() and path.suffix == ".png"
    img = _read_png(path)
    h, w = img.shape[:2]
    assert (w, h) == (1024, 768)
    assert img.std() > 10 and len(np.unique(img.reshape(-1, 3), axis=0)) > 100  # not uniform
    cmap = matplotlib.colormaps["viridis"]
    surface_area = img[:, : int(0.85 * w)]  # left of the colour bar
    low, high = _near(surface_area, cmap(0.0)), _near(surface_area, cmap(1.0))
    assert low.sum() > 500, "colour map's low end missing from the surface"
    assert high.sum() > 20, "colour map's high end (bump top) missing from the surface"
    bar = img[:, int(0.85 * w):]
    assert _near(bar, cmap(0.0)).sum() > 50 and _near(bar, cmap(1.0)).sum() > 50  # colour bar
    assert (img == 255).all(axis=2).mean() > 0.2  # white background around the scene


def test_fixed_z_range_and_camera_make_runs_comparable(tmp_path, can_render):
    m = _bump(32)
    a = render_height_map(m, tmp_path / "a_render.png", title="t", z_range_m=(0, 40e-9),
                          window_size=(800, 600))
    b = render_height_map(m.with_z(m.z * 0.5), tmp_path / "b_render.png", title="t",
                          z_range_m=(0, 40e-9), window_size=(800, 600))
    ia, ib = _read_png(a), _read_png(b)
    assert ia.shape == ib.shape == (600, 800, 3)
    # same frame (axes, bar, background) but a lower bump: images differ only partly
    diff = np.abs(ia - ib).max(axis=2) > 30
    assert 0.001 < diff.mean() < 0.3


def test_top_camera_and_mesh(tmp_path, can_render):
    import trimesh

    m = _bump(40)
    render_height_map(m, tmp_path / "top_render.png", title="top", camera="top")
    # a height-field mesh of the same bump, vertices in metres
    xx, yy = np.meshgrid(m.x, m.y)
    verts = np.column_stack([xx.ravel(), yy.ravel(), m.z.ravel()])
    ny, nx = m.shape
    i = (np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]).ravel()
    faces = np.vstack([np.column_stack([i, i + 1, i + nx]),
                       np.column_stack([i + 1, i + nx + 1, i + nx])])
    mesh = trimesh.Trimesh(verts, faces, process=False)
    p = render_mesh(mesh, tmp_path / "mesh_render.png", title="true sample")
    img = _read_png(p)
    assert img.shape[:2] == (768, 1024) and img.std() > 10
    cmap = matplotlib.colormaps["viridis"]
    assert _near(img[:, :870], cmap(1.0)).sum() > 20


def test_fresh_process_renders_without_x_server_warning(tmp_path, can_render):
    out = tmp_path / "fresh_render.png"
    code = textwrap.dedent(f"""
        import time, numpy as np
        from afmsim.render import render_height_map
        from afmsim.samples.heightmap import HeightMap
        x = np.linspace(-1, 1, 256); xx, yy = np.meshgrid(x, x)
        m = HeightMap(20e-9 * np.exp(-(xx**2 + yy**2) / 0.1), (10e-9, 10e-9))
        t = time.perf_counter(); render_height_map(m, {str(out)!r}, title="first")
        t1 = time.perf_counter() - t
        t = time.perf_counter(); render_height_map(m, {str(out)!r}, title="second")
        print(f"TIMING first={{t1:.2f}}s second={{time.perf_counter() - t:.2f}}s")
    """)
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "VTK_DEFAULT_OPENGL_WINDOW")}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + [p for p in [env.get("PYTHONPATH")] if p])
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "bad X server" not in proc.stderr, proc.stderr
    assert "TIMING" in proc.stdout
    assert out.stat().st_size > 10_000
    print(proc.stdout.strip())


def test_user_window_choice_is_not_clobbered():
    code = ("import os, pyvista; import afmsim.render as r; "
            "print(os.environ['VTK_DEFAULT_OPENGL_WINDOW'], pyvista.OFF_SCREEN, r.EGL_DEFAULT_CHOSEN)")
    env = dict(os.environ, VTK_DEFAULT_OPENGL_WINDOW="vtkXOpenGLRenderWindow", PYTHONPATH=str(REPO))
    env.pop("PYVISTA_OFF_SCREEN", None)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["vtkXOpenGLRenderWindow", "False", "False"]


def test_interactive_without_display_is_a_clear_error(tmp_path, monkeypatch):
    if not sys.platform.startswith("linux"):
        pytest.skip("display detection is tested on Linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    with pytest.raises(RenderingUnavailable, match="display"):
        render_height_map(_bump(8), tmp_path / "i_render.png", title="x", interactive=True)


def test_z_exaggeration_is_1_2_5_and_never_below_one():
    assert z_exaggeration_for(10e-6, 100e-9) == 20.0  # raw 30 → 20
    assert z_exaggeration_for(2e-6, 20e-9) == 20.0  # raw 30
    assert z_exaggeration_for(1e-6, 1e-9) == 200.0  # raw 300
    assert z_exaggeration_for(1e-6, 5e-7) == 1.0
    assert z_exaggeration_for(1e-6, 0.0) == 1.0


def test_rendering_available_reports_a_reason():
    ok, reason = rendering_available()
    assert isinstance(ok, bool) and isinstance(reason, str) and reason
