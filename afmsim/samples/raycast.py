"""Mesh → :class:`HeightMap` by casting vertical rays (straight down, −z) against a triangle mesh.

The mesh is the sample; the height map is derived from it on whatever grid the caller asks for.
Each pixel centre ``(x, y)`` gets the z of the *first* surface a ray coming down from above the
mesh meets (``trimesh``'s ray/triangle intersector, ``multiple_hits=False``), i.e. the top
surface that an AFM tip coming from above can reach; overhangs are hidden, as for a real AFM.

Numerics: trimesh's ray/triangle test uses absolute tolerances (~1e-13) that are meant for meshes
in "human" units, and SI meshes have triangle areas ~1e-14 m². Rays are therefore cast on a copy
scaled so that the mesh's largest xy extent is O(10) units, then scaled back to metres.
"""

from __future__ import annotations

import numpy as np
import trimesh

from .heightmap import HeightMap

__all__ = ["mesh_to_heightmap", "pixel_grid"]


def pixel_grid(shape, extent=None, *, pixel_size=None, origin=None, center=None, bounds=None):
    """Resolve a pixel grid: returns ``(pixel_size, origin)`` for a map of ``shape = (ny, nx)``.

    Give exactly one of ``extent = (width, height)`` [m] (the field of view: ``nx·dx`` wide,
    ``ny·dy`` high, pixel centres half a pixel inside) or ``pixel_size = (dx, dy)`` [m].
    The field is placed by ``origin`` (centre of pixel [0, 0], m) or ``center`` (field centre, m);
    with neither, it is centred on ``bounds`` (``(xmin, ymin, xmax, ymax)``) or on (0, 0).
    """
    ny, nx = (int(v) for v in shape)
    if ny < 2 or nx < 2:
        raise ValueError(f"grid shape must be at least (2, 2), got {shape}")
    if (extent is None) == (pixel_size is None):
        if extent is None and bounds is not None:
            extent = (bounds[2] - bounds[0], bounds[3] - bounds[1])
        else:
            raise ValueError("give exactly one of extent=(width, height) or pixel_size=(dx, dy)")
    if extent is not None:
        w, h = (float(v) for v in np.broadcast_to(np.asarray(extent, float), (2,)))
        if not (w > 0 and h > 0):
            raise ValueError(f"extent must be > 0, got {extent}")
        dx, dy = w / nx, h / ny
    else:
        dx, dy = (float(v) for v in np.broadcast_to(np.asarray(pixel_size, float), (2,)))
        if not (dx > 0 and dy > 0):
            raise ValueError(f"pixel_size must be > 0, got {pixel_size}")
    if origin is not None and center is not None:
        raise ValueError("give origin or center, not both")
    if origin is None:
        if center is None:
            if bounds is not None:
                center = (0.5 * (bounds[0] + bounds[2]), 0.5 * (bounds[1] + bounds[3]))
            else:
                center = (0.0, 0.0)
        cx, cy = (float(v) for v in center)
        origin = (cx - 0.5 * (nx - 1) * dx, cy - 0.5 * (ny - 1) * dy)
    return (dx, dy), (float(origin[0]), float(origin[1]))


def mesh_to_heightmap(
    mesh: trimesh.Trimesh,
    shape=(256, 256),
    extent=None,
    *,
    pixel_size=None,
    origin=None,
    center=None,
    background: float | None = None,
    engine: str = "auto",
) -> HeightMap:
    """Height map of ``mesh`` (coordinates in metres) seen from +z, by vertical ray casting.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Sample surface in metres (z up). Need not be watertight, but a closed mesh is the norm.
    shape : (ny, nx)
        Pixels of the map (rows = y lines, columns = x, left → right).
    extent, pixel_size, origin, center
        The grid, see :func:`pixel_grid`. Default: the mesh's xy bounding box, centred on it.
    background : float, optional
        Height [m] given to pixels whose ray misses the mesh. Default: the mesh's lowest z.
    engine : {"auto", "vertical", "trimesh"}
        ``"trimesh"``: trimesh's ``RayMeshIntersector`` (``intersects_id``, first hit per ray; uses
        Embree when ``embreex`` is installed, otherwise trimesh's pure-Python r-tree intersector,
        ~6–10 µs per ray: ~10 s for 256², ~30 s for 512²).
        ``"vertical"``: the same ray/triangle test specialised to rays along −z and vectorised
        (each upward-facing triangle's xy bounding box → candidate pixels, barycentric test in
        xy, hit z interpolated on the triangle's plane, first hit = highest z): identical results
        to float rounding, ~0.1–0.5 s for 512².
        ``"auto"``: trimesh+Embree if available, else ``"vertical"``.

    Returns
    -------
    HeightMap
        ``z[k, l]`` = height of the first hit of a ray going down through pixel centre (x_l, y_k).
    """
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError("mesh_to_heightmap needs a non-empty trimesh.Trimesh")
    b = mesh.bounds
    (dx, dy), org = pixel_grid(shape, extent, pixel_size=pixel_size, origin=origin, center=center,
                               bounds=(b[0, 0], b[0, 1], b[1, 0], b[1, 1]))
    ny, nx = (int(v) for v in shape)
    if background is None:
        background = float(b[0, 2])
    if engine == "auto":
        engine = "trimesh" if trimesh.ray.has_embree else "vertical"
    if engine == "trimesh":
        z = _cast_trimesh(mesh, nx, ny, (dx, dy), org)
    elif engine == "vertical":
        z = _cast_vertical(mesh, nx, ny, (dx, dy), org)
    else:
        raise ValueError(f"engine must be 'auto', 'vertical' or 'trimesh', got {engine!r}")
    z[np.isnan(z)] = background
    return HeightMap(z, (dx, dy), org)


def _scaled(mesh):
    """Shift to the bbox centre and scale to O(10) units (see module docstring)."""
    b = mesh.bounds
    span = float(np.max(b[1] - b[0]))
    if not span > 0:
        raise ValueError("mesh has zero extent")
    return 10.0 / span, 0.5 * (b[0] + b[1])


def _cast_trimesh(mesh, nx, ny, pixel_size, org, chunk=65536):
    s, c = _scaled(mesh)
    work = trimesh.Trimesh(vertices=(mesh.vertices - c) * s, faces=mesh.faces, process=False)
    inter = work.ray  # embree if available, else trimesh.ray.ray_triangle.RayMeshIntersector
    xs = (org[0] + pixel_size[0] * np.arange(nx) - c[0]) * s
    ys = (org[1] + pixel_size[1] * np.arange(ny) - c[1]) * s
    X, Y = np.meshgrid(xs, ys)
    z_top = (mesh.bounds[1, 2] - c[2]) * s + 1.0
    n = X.size
    origins = np.column_stack([X.ravel(), Y.ravel(), np.full(n, z_top)])
    out = np.full(n, -np.inf)
    for i0 in range(0, n, chunk):
        o = origins[i0:i0 + chunk]
        d = np.broadcast_to(np.array([0.0, 0.0, -1.0]), o.shape)
        _, idx_ray, loc = inter.intersects_id(o, d, multiple_hits=False, return_locations=True)
        if len(idx_ray):
            np.maximum.at(out[i0:i0 + chunk], idx_ray, loc[:, 2])
    out = np.where(np.isfinite(out), out / s + c[2], np.nan)
    return out.reshape(ny, nx)


def _cast_vertical(mesh, nx, ny, pixel_size, org, max_pairs=4_000_000):
    s, c = _scaled(mesh)
    dx, dy = pixel_size[0] * s, pixel_size[1] * s
    ox, oy = (org[0] - c[0]) * s, (org[1] - c[1]) * s
    tri = (mesh.triangles - c) * s  # (F, 3, 3)
    # signed doubled xy area; a downward ray first enters a closed, outward-wound mesh through a face
    # with n_z > 0, so those suffice there; otherwise keep every non-vertical face.
    e1, e2 = tri[:, 1, :2] - tri[:, 0, :2], tri[:, 2, :2] - tri[:, 0, :2]
    a2 = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    eps = 1e-12 * float(np.max(np.abs(a2))) if len(a2) else 0.0
    keep = a2 > eps if mesh.is_volume else np.abs(a2) > eps
    tri, a2 = tri[keep], a2[keep]
    lo, hi = tri[:, :, :2].min(1), tri[:, :, :2].max(1)
    ix0 = np.maximum(np.ceil((lo[:, 0] - ox) / dx - 1e-9), 0).astype(np.int64)
    ix1 = np.minimum(np.floor((hi[:, 0] - ox) / dx + 1e-9), nx - 1).astype(np.int64)
    iy0 = np.maximum(np.ceil((lo[:, 1] - oy) / dy - 1e-9), 0).astype(np.int64)
    iy1 = np.minimum(np.floor((hi[:, 1] - oy) / dy + 1e-9), ny - 1).astype(np.int64)
    wx, wy = ix1 - ix0 + 1, iy1 - iy0 + 1
    ok = (wx > 0) & (wy > 0)
    tri, a2, ix0, iy0, wx, wy = tri[ok], a2[ok], ix0[ok], iy0[ok], wx[ok], wy[ok]
    npairs = wx * wy
    out = np.full(nx * ny, -np.inf)
    cum = np.cumsum(npairs)
    start = 0
    while start < len(tri):
        base = cum[start - 1] if start else 0
        stop = max(start + 1, int(np.searchsorted(cum, base + max_pairs, side="right")))
        sl = slice(start, stop)
        cnt = npairs[sl]
        t_id = np.repeat(np.arange(start, stop), cnt)
        local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        px = ix0[t_id] + local % wx[t_id]
        py = iy0[t_id] + local // wx[t_id]
        X, Y = ox + px * dx, oy + py * dy
        T = tri[t_id]
        # barycentric coordinates of (X, Y) in the triangle's xy projection
        l1 = ((X - T[:, 0, 0]) * (T[:, 2, 1] - T[:, 0, 1]) - (Y - T[:, 0, 1]) * (T[:, 2, 0] - T[:, 0, 0])) / a2[t_id]
        l2 = ((T[:, 1, 0] - T[:, 0, 0]) * (Y - T[:, 0, 1]) - (T[:, 1, 1] - T[:, 0, 1]) * (X - T[:, 0, 0])) / a2[t_id]
        l0 = 1.0 - l1 - l2
        tol = -1e-9
        hit = (l0 >= tol) & (l1 >= tol) & (l2 >= tol)
        z = l0 * T[:, 0, 2] + l1 * T[:, 1, 2] + l2 * T[:, 2, 2]
        np.maximum.at(out, (py * nx + px)[hit], z[hit])
        start = stop
    out = np.where(np.isfinite(out), out / s + c[2], np.nan)
    return out.reshape(ny, nx)
