"""3D height views: warped height-map surfaces and true sample meshes, written as PNG.

Display conventions (the same for every view, so images of different runs compare)
----------------------------------------------------------------------------------
* x and y are drawn in **µm**; the grid's axis labels read "x (µm)", "y (µm)".
* Heights are coloured with a fixed colour map (``viridis``) over ``z_range_m`` with a colour
  bar labelled "height (nm)" (the z scale of the view; the grid's z range is also set in nm),
  while the drawn z is exaggerated by a factor written in the view ("vertical exaggeration
  ×E", the line under the title, with pixel count, scan size in µm and z range in nm); colour-bar
  labels are whole nanometres on ranges of 20 nm or more. E is a
  1-2-5 number chosen from the lateral size and ``z_range_m`` (see
  :func:`z_exaggeration_for`), so runs rendered with the same ``z_range_m`` on the same scan
  size get the same E and the same camera.
* The camera is a fixed direction (``CAMERAS``) fitted to the fixed bounds
  (lateral extent × ``z_range_m``), not to the data.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np
import pyvista as pv

from afmsim.render.probe import RenderingUnavailable
from afmsim.samples.heightmap import HeightMap

__all__ = ["render_height_map", "render_mesh", "z_exaggeration_for", "CAMERAS", "DEFAULT_CMAP"]

DEFAULT_CMAP = "viridis"

#: Named camera directions: (azimuth°, elevation°, zoom). Azimuth is measured in the x-y plane
#: from +x; -120° puts the camera at the front-left (−x, −y side), so x runs left → right and
#: the first scan line (row 0, smallest y) is in front. "top" looks straight down (y up).
CAMERAS = {
    "iso": (-120.0, 35.0, 1.15),
    "front": (-90.0, 20.0, 1.15),
    "top": (-90.0, 90.0, 1.1),
}

_TARGET_RELIEF = 0.3  # drawn z span / largest lateral side that the exaggeration aims at
_MICRO = 1e6
_NANO = 1e9


def z_exaggeration_for(lateral_extent_m: float, z_span_m: float,
                       target: float = _TARGET_RELIEF) -> float:
    """Vertical exaggeration E (a 1-2-5 number ≥ 1) drawing ``z_span_m`` as about
    ``target`` × ``lateral_extent_m`` (rounded down so the relief never exceeds it)."""
    if not (z_span_m > 0 and lateral_extent_m > 0):
        return 1.0
    raw = target * lateral_extent_m / z_span_m
    if raw <= 1.0:
        return 1.0
    decade = 10.0 ** math.floor(math.log10(raw))
    for m in (5.0, 2.0, 1.0):
        if m * decade <= raw * (1 + 1e-12):
            return m * decade
    return decade  # pragma: no cover


def _nm(z_m: float) -> str:
    """A height (m) as nm text: whole nanometres from 20 nm up, never in e-notation."""
    v = z_m * _NANO
    return f"{v:.0f}" if abs(v) >= 20 else f"{v:.2g}"


def _z_limits(z_m: np.ndarray, z_range_m) -> tuple[float, float]:
    lo, hi = (float(np.min(z_m)), float(np.max(z_m))) if z_range_m is None else \
        (float(z_range_m[0]), float(z_range_m[1]))
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        raise ValueError(f"z_range_m must be finite (low, high) with low ≤ high, got {z_range_m}")
    if hi == lo:  # flat: give the colour map something to span
        pad = max(abs(lo) * 1e-3, 0.5e-9)
        lo, hi = lo - pad, hi + pad
    return lo, hi


def _plotter(window_size, interactive: bool) -> pv.Plotter:
    w, h = (int(v) for v in window_size)
    if w < 1 or h < 1:
        raise ValueError(f"window_size must be positive, got {window_size}")
    if not interactive:
        return pv.Plotter(off_screen=True, window_size=(w, h))
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        raise RenderingUnavailable(
            "interactive=True needs a display, but DISPLAY is not set (headless machine?); "
            "render to a PNG with interactive=False instead")
    # The package default is the off-screen EGL window; VTK reads the variable at each window
    # creation, so switch to X11 for this one plotter only (a user's own choice is kept).
    key = "VTK_DEFAULT_OPENGL_WINDOW"
    old = os.environ.get(key)
    if sys.platform.startswith("linux") and old == "vtkEGLRenderWindow":
        os.environ[key] = "vtkXOpenGLRenderWindow"
    try:
        p = pv.Plotter(off_screen=False, window_size=(w, h))
    finally:
        if old is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = old
    if type(p.ren_win).__name__ in ("vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow"):
        p.close()
        raise RenderingUnavailable(
            f"interactive=True: VTK could not open an on-screen window on DISPLAY="
            f"{os.environ.get('DISPLAY')!r} (got the off-screen {type(p.ren_win).__name__})")
    return p


def _set_camera(p: pv.Plotter, camera, bounds) -> None:
    """Fixed camera: a named direction / (azimuth, elevation[, zoom]) fitted to ``bounds``, or a
    pyvista camera position ``[(pos), (focal), (up)]`` in display units (µm) used as-is."""
    if isinstance(camera, str):
        try:
            camera = CAMERAS[camera]
        except KeyError:
            raise ValueError(f"unknown camera {camera!r}; named cameras: {sorted(CAMERAS)}") \
                from None
    cam = list(camera)
    if len(cam) == 3 and all(np.ndim(c) == 1 and len(c) == 3 for c in cam):
        p.camera_position = [tuple(map(float, c)) for c in cam]
        return
    az, el = float(cam[0]), float(cam[1])
    zoom = float(cam[2]) if len(cam) > 2 else 1.0
    a, e = math.radians(az), math.radians(el)
    d = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    c = np.array([(bounds[0] + bounds[1]) / 2, (bounds[2] + bounds[3]) / 2,
                  (bounds[4] + bounds[5]) / 2])
    up = (0.0, 1.0, 0.0) if el >= 89.9 else (0.0, 0.0, 1.0)
    p.camera_position = [tuple(c + d), tuple(c), up]
    p.reset_camera(bounds=bounds)
    p.camera.zoom(zoom)
    # Shift the projection centre so the scene sits left of the colour bar (no overlap).
    p.camera.SetWindowCenter(0.14, 0.0)


def _finish(p: pv.Plotter, mesh: pv.DataSet, *, path, title, clim_nm, axes_um_nm, bounds,
            exaggeration, info, camera, cmap, interactive) -> Path:
    path = Path(path)
    p.set_background("white")
    p.add_mesh(mesh, scalars="height (nm)", cmap=cmap, clim=clim_nm, show_scalar_bar=False,
               ambient=0.3, diffuse=0.7, specular=0.1, smooth_shading=True)
    span = clim_nm[1] - clim_nm[0]
    p.add_scalar_bar(title="height (nm)", color="black", vertical=True, n_labels=5,
                     fmt="%.0f" if span >= 20 else "%.1f" if span >= 2 else "%.3g",
                     position_x=0.88, position_y=0.2, width=0.07, height=0.6,
                     title_font_size=18, label_font_size=15)
    # Grid labels: x/y in µm (display units); the z range is given in nm (true heights). 2-D
    # labels because VTK's 3-D axis text drops the "µ"; the colour bar carries the z scale.
    p.show_grid(bounds=bounds, axes_ranges=axes_um_nm, xtitle="x (µm)", ytitle="y (µm)",
                ztitle="z (nm)", color="black", font_size=11, n_xlabels=5, n_ylabels=5,
                n_zlabels=3, fmt="%.3g", location="outer", use_2d=True)
    p.add_text(title, position="upper_edge", font_size=14, color="black")
    # Second line under the title (the lower edge belongs to the grid's labels).
    p.add_text(f"vertical exaggeration ×{exaggeration:g}   ·   {info}", position=(12, p.window_size[1] - 58),
               font_size=9, color="black")
    _set_camera(p, camera, bounds)
    path.parent.mkdir(parents=True, exist_ok=True)
    if interactive:
        p.show(screenshot=str(path), auto_close=True)
    else:
        image = p.screenshot(str(path))
        p.close()
        if image is None or float(np.std(image)) == 0.0:  # a GL stack that "renders" nothing
            path.unlink(missing_ok=True)
            raise RenderingUnavailable(f"{path.name}: the off-screen render came out blank")
    return path


def render_height_map(hmap: HeightMap, path, *, title: str, z_range_m=None,
                      window_size=(1024, 768), camera="iso", cmap: str = DEFAULT_CMAP,
                      z_exaggeration: float | None = None, interactive: bool = False) -> Path:
    """Render a height map as a warped, height-coloured 3D surface and save it as PNG.

    Parameters
    ----------
    hmap : HeightMap
        Heights in metres on their physical grid (drawn at pixel centres).
    path : str or Path
        Output PNG (parent folders are created).
    title : str
        Text at the top of the image.
    z_range_m : (float, float), optional
        Colour-map limits and vertical scale in metres; defaults to the map's own min/max.
        Pass the same range for images that should be compared.
    window_size : (int, int)
        Image size in pixels (width, height); default 1024×768.
    camera : str or tuple
        A name in :data:`CAMERAS` ("iso", "front", "top"), ``(azimuth°, elevation°[, zoom])``,
        or a pyvista camera position ``[(pos), (focal), (up)]`` in display units (µm).
    cmap : str
        Matplotlib colour-map name.
    z_exaggeration : float, optional
        Vertical exaggeration; by default :func:`z_exaggeration_for` (lateral size, z range).
    interactive : bool
        Open an on-screen window (needs a display; raises :class:`RenderingUnavailable`
        otherwise); the PNG is written when the window closes.

    Returns
    -------
    Path
        The PNG written.
    """
    if not isinstance(hmap, HeightMap):
        raise TypeError(f"expected HeightMap, got {type(hmap).__name__}")
    lo, hi = _z_limits(hmap.z, z_range_m)
    ny, nx = hmap.shape
    dx, dy = hmap.pixel_size
    x0, y0 = hmap.origin
    ext_x, ext_y = (nx - 1) * dx, (ny - 1) * dy
    e = float(z_exaggeration) if z_exaggeration is not None else \
        z_exaggeration_for(max(ext_x, ext_y), hi - lo)
    zs = _MICRO * e  # metres of height → drawn µm

    grid = pv.ImageData(dimensions=(nx, ny, 1), spacing=(dx * _MICRO, dy * _MICRO, 1.0),
                        origin=(x0 * _MICRO, y0 * _MICRO, 0.0))
    grid.point_data["zdisp"] = (hmap.z * zs).ravel()  # C order of (ny, nx): x varies fastest
    surf = grid.warp_by_scalar("zdisp", factor=1.0, normal=(0.0, 0.0, 1.0))
    surf.point_data["height (nm)"] = (hmap.z * _NANO).ravel()

    bounds = (x0 * _MICRO, (x0 + ext_x) * _MICRO, y0 * _MICRO, (y0 + ext_y) * _MICRO,
              lo * zs, hi * zs)
    axes = list(bounds[:4]) + [lo * _NANO, hi * _NANO]
    info = (f"{nx}×{ny} px, {nx * dx * _MICRO:.3g}×{ny * dy * _MICRO:.3g} µm, "
            f"z {_nm(lo)}…{_nm(hi)} nm")
    p = _plotter(window_size, interactive)
    return _finish(p, surf, path=path, title=title, clim_nm=(lo * _NANO, hi * _NANO),
                   axes_um_nm=axes, bounds=bounds, exaggeration=e, info=info, camera=camera,
                   cmap=cmap, interactive=interactive)


def render_mesh(mesh, path, *, title: str = "sample mesh", z_range_m=None,
                window_size=(1024, 768), camera="iso", cmap: str = DEFAULT_CMAP,
                z_exaggeration: float | None = None, interactive: bool = False) -> Path:
    """Render a triangle mesh (e.g. the true sample, ``trimesh.Trimesh``, vertices in metres)
    coloured by height, with the same display conventions as :func:`render_height_map`
    (x/y in µm, colour bar and z labels in nm, documented vertical exaggeration; pass
    ``z_exaggeration=1`` for true proportions). ``mesh`` may also be a ``pyvista.PolyData``
    in metres. Returns the PNG path."""
    if isinstance(mesh, pv.PolyData):
        verts = np.asarray(mesh.points, dtype=np.float64)
        poly = mesh.triangulate().copy()
    else:
        verts = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces, dtype=np.int64)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError("mesh.faces must be an (n, 3) triangle array")
        cells = np.hstack([np.full((len(faces), 1), 3, dtype=np.int64), faces]).ravel()
        poly = pv.PolyData(verts.copy(), cells)
    if len(verts) == 0:
        raise ValueError("mesh has no vertices")
    lo, hi = _z_limits(verts[:, 2], z_range_m)
    (xa, ya, _), (xb, yb, _) = verts.min(axis=0), verts.max(axis=0)
    e = float(z_exaggeration) if z_exaggeration is not None else \
        z_exaggeration_for(max(xb - xa, yb - ya), hi - lo)
    zs = _MICRO * e
    pts = verts.copy()
    pts[:, :2] *= _MICRO
    pts[:, 2] *= zs
    poly.points = pts
    poly.point_data["height (nm)"] = verts[:, 2] * _NANO
    bounds = (xa * _MICRO, xb * _MICRO, ya * _MICRO, yb * _MICRO, lo * zs, hi * zs)
    axes = list(bounds[:4]) + [lo * _NANO, hi * _NANO]
    info = (f"{len(verts)} vertices, {(xb - xa) * _MICRO:.3g}×{(yb - ya) * _MICRO:.3g} µm, "
            f"z {_nm(lo)}…{_nm(hi)} nm")
    p = _plotter(window_size, interactive)
    return _finish(p, poly, path=path, title=title, clim_nm=(lo * _NANO, hi * _NANO),
                   axes_um_nm=axes, bounds=bounds, exaggeration=e, info=info, camera=camera,
                   cmap=cmap, interactive=interactive)
