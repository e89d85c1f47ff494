"""PDMS spherical micro-lens array as a watertight triangle mesh (trimesh), and its height map.

Geometry (SI units, metres): spherical caps of base diameter ``D = 2a`` and sag ``s`` (apex height
above the flat) sit on the top face (z = 0) of a flat slab of thickness ``base_thickness``
(bottom at z = −base_thickness). Cap radius of curvature ``R = (a² + s²) / (2 s)``; the height of
a cap at distance ρ from its centre is ``z(ρ) = sqrt(R² − ρ²) − (R − s)`` for ρ ≤ a, else 0.

Default parameters — datasheet row "PDMS micro-lenses" (diameter 3–10 µm, pitch 1–1.5× diameter,
sag 0.3–2 µm), which is an **L (low) confidence** row; treat every default as a scenario parameter.
They are chosen to match the reference paper's micro-lens images (Wang et al. 2015, §3.3: one
lens roughly centred in a 10–20 µm scan): D = 6 µm, sag = 1 µm, pitch = 8 µm (1.33 D), a 3×3
square array centred on (0, 0), so a centred 10–20 µm scan shows one lens whole and parts of its
neighbours.

Mesh construction: each cap is meshed with concentric rings of vertices placed *on the sphere*
(equal polar-angle steps, ring vertex counts ∝ circumference, so edges are ≈ ``edge_length``
long), the rim ring lies exactly on the circle ρ = a at z = 0, and a guard ring at base height
just outside it keeps flat triangles off the cap. The flat base gets a coarse point grid. The top
is a height field (every vertex holds its exact surface height) triangulated in xy: one cap is
Delaunay-triangulated and translated to every lens (all caps are alike), the flat part is the
Delaunay triangulation of the rims, guard rings and grid less the triangles inside a rim, and the
two share every rim edge. The top's boundary edges are extruded down to the slab bottom (side
walls), and the bottom is a fan from its centre — one closed, consistently wound (watertight) mesh.
The faceting error of an inscribed triangle of circumradius r is ≈ r² / (2R) (≈ 1 nm for the
default 150 nm edges and R = 5 µm); :meth:`MicroLensArray.max_facet_error` gives the bound used
by the tests.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import Delaunay, cKDTree

from .heightmap import HeightMap
from .raycast import mesh_to_heightmap

__all__ = [
    "MicroLensArray",
    "microlens_mesh",
    "microlens_heightmap",
    "DEFAULT_MESH_PATH",
    "regenerate_default_mesh",
    "load_default_mesh",
]

#: default mesh file, coordinates in **micrometres** (PLY has no unit field)
DEFAULT_MESH_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                                 "samples", "microlens_array.ply")
DEFAULT_MESH_UNIT = 1e-6


def _counter_clockwise(faces: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``faces`` less the degenerate (collinear) ones, each wound counter-clockwise in ``xy``
    (normals up); ``xy`` in units of the edge length so the area threshold is scale-free."""
    a, b, c = (xy[faces[:, k]] for k in range(3))
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    keep = np.abs(area2) > 1e-9
    faces, flip = faces[keep].copy(), area2[keep] < 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces


def _distance_to_nearest(points: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """Distance [m] from each (x, y) point to the nearest lens centre."""
    return cKDTree(centers).query(points)[0]


@dataclass(frozen=True)
class MicroLensArray:
    """Spherical-cap micro-lens array on a slab. All lengths in metres.

    Attributes
    ----------
    diameter : float
        Lens base diameter D [m]. Default 6 µm (datasheet 3–10 µm, L confidence).
    sag : float
        Lens height above the flat s [m], 0 < s ≤ D/2 (no overhang). Default 1 µm (datasheet 0.3–2 µm, L).
    pitch : float
        Centre-to-centre lens spacing [m], ≥ D. Default 8 µm (1.33 D; datasheet 1–1.5 D, L).
    arrangement : {"square", "hexagonal"}
        Lattice. Hexagonal: rows ``pitch·√3/2`` apart, odd rows shifted by ``pitch/2``.
    n_lenses : (int, int)
        Lenses along x and y (rows). Default (3, 3).
    center : (float, float)
        Position of the array centre [m]. Default (0, 0): the middle lens sits at the origin.
    margin : float
        Flat border between the outermost lens rims and the slab edge [m]. Default 1 µm.
    base_thickness : float
        Slab thickness below the flat top z = 0 [m]. Default 1 µm.
    edge_length : float
        Target mesh edge length on the caps [m] (mesh resolution). Default 150 nm.
    """

    diameter: float = 6e-6
    sag: float = 1e-6
    pitch: float = 8e-6
    arrangement: str = "square"
    n_lenses: tuple[int, int] = (3, 3)
    center: tuple[float, float] = (0.0, 0.0)
    margin: float = 1e-6
    base_thickness: float = 1e-6
    edge_length: float = 150e-9

    def __post_init__(self):
        if not (self.diameter > 0 and self.sag > 0):
            raise ValueError(f"diameter and sag must be > 0, got {self.diameter}, {self.sag}")
        if self.sag > self.diameter / 2:
            raise ValueError(f"sag {self.sag} > diameter/2: cap larger than a hemisphere (overhang)")
        if self.pitch < self.diameter * (1 - 1e-9):
            raise ValueError(f"pitch {self.pitch} < diameter {self.diameter}: lenses would overlap")
        if self.arrangement not in ("square", "hexagonal"):
            raise ValueError(f"arrangement must be 'square' or 'hexagonal', got {self.arrangement!r}")
        nx, ny = (int(v) for v in self.n_lenses)
        if nx < 1 or ny < 1:
            raise ValueError(f"n_lenses must be ≥ 1 in both axes, got {self.n_lenses}")
        if not (self.margin >= 0 and self.base_thickness > 0 and self.edge_length > 0):
            raise ValueError("margin ≥ 0, base_thickness > 0 and edge_length > 0 required")

    # ------------------------------------------------------------------ geometry
    @property
    def radius_of_curvature(self) -> float:
        """R = (a² + s²)/(2s) [m]."""
        a = self.diameter / 2
        return (a * a + self.sag * self.sag) / (2 * self.sag)

    def lens_centers(self) -> np.ndarray:
        """(n, 2) lens centre positions [m]."""
        nx, ny = (int(v) for v in self.n_lenses)
        p = self.pitch
        if self.arrangement == "square":
            gx, gy = np.meshgrid(np.arange(nx) * p, np.arange(ny) * p)
        else:
            gx, gy = np.meshgrid(np.arange(nx) * p, np.arange(ny) * p * np.sqrt(3) / 2)
            gx = gx + (np.arange(ny)[:, None] % 2) * p / 2
        c = np.column_stack([gx.ravel(), gy.ravel()])
        c -= 0.5 * (c.min(0) + c.max(0))
        return c + np.asarray(self.center, float)

    def slab_bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the slab [m]."""
        c = self.lens_centers()
        r = self.diameter / 2 + self.margin
        return (c[:, 0].min() - r, c[:, 1].min() - r, c[:, 0].max() + r, c[:, 1].max() + r)

    def height(self, x, y) -> np.ndarray:
        """Exact analytic top-surface height [m] at points (x, y) [m] (0 on the flat)."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        a, R, s = self.diameter / 2, self.radius_of_curvature, self.sag
        z = np.zeros(x.shape)
        for cx, cy in self.lens_centers():
            rho2 = (x - cx) ** 2 + (y - cy) ** 2
            inside = rho2 < a * a
            z[inside] = np.maximum(z[inside], np.sqrt(R * R - rho2[inside]) - (R - s))
        return z

    # ------------------------------------------------------------------ mesh
    def _cap_template(self):
        """One cap centred at the origin: vertices (apex, rings, rim ring last; metres), its
        triangles (counter-clockwise in xy) and the rim vertex count.

        Every lens is a translated copy, so the cap is triangulated once. Ring phases are drawn
        from a fixed generator so the mesh is reproducible.
        """
        a, R, s, h = self.diameter / 2, self.radius_of_curvature, self.sag, self.edge_length
        theta_max = np.arcsin(min(1.0, a / R))
        n_rings = max(2, int(np.ceil(R * theta_max / h)))
        n_rim = max(12, int(np.ceil(2 * np.pi * a / h)))
        rng = np.random.default_rng(0)
        pts = [np.array([[0.0, 0.0, s]])]
        for k in range(1, n_rings + 1):
            th = k * theta_max / n_rings
            rho = a if k == n_rings else R * np.sin(th)
            z = 0.0 if k == n_rings else R * np.cos(th) - (R - s)
            m = n_rim if k == n_rings else max(6, int(np.ceil(2 * np.pi * rho / h)))
            phi = 2 * np.pi * (np.arange(m) + rng.uniform()) / m
            pts.append(np.column_stack([rho * np.cos(phi), rho * np.sin(phi), np.full(m, z)]))
        cap = np.vstack(pts)
        return cap, _counter_clockwise(Delaunay(cap[:, :2] / h).simplices, cap[:, :2] / h), n_rim

    def _flat_points(self) -> np.ndarray:
        """(x, y) of the flat top outside the caps [m]: a guard ring just outside every rim (keeps
        flat triangles off the caps), a coarse background grid and the slab outline."""
        a, h = self.diameter / 2, self.edge_length
        centers = self.lens_centers()
        guard_r = a + 0.5 * h
        m = max(12, int(np.ceil(2 * np.pi * guard_r / h)))
        phi = 2 * np.pi * (np.arange(m) + 0.5) / m
        ring = guard_r * np.column_stack([np.cos(phi), np.sin(phi)])
        guards = (centers[:, None, :] + ring[None]).reshape(-1, 2)
        x0, y0, x1, y1 = self.slab_bounds()
        h_bg = max(4 * h, min(self.pitch / 4, 1e-6))
        nbx, nby = max(2, int(np.ceil((x1 - x0) / h_bg)) + 1), max(2, int(np.ceil((y1 - y0) / h_bg)) + 1)
        bx, by = np.linspace(x0, x1, nbx), np.linspace(y0, y1, nby)
        gx, gy = np.meshgrid(bx[1:-1], by[1:-1])
        grid = np.column_stack([gx.ravel(), gy.ravel()])
        outline = np.vstack([
            np.column_stack([bx, np.full(nbx, y0)]), np.column_stack([bx, np.full(nbx, y1)]),
            np.column_stack([np.full(nby - 2, x0), by[1:-1]]), np.column_stack([np.full(nby - 2, x1), by[1:-1]]),
        ])
        # guard points inside a touching neighbour, and grid points near any rim, are dropped
        keep_guard = _distance_to_nearest(guards, centers) > a + 1e-3 * h
        keep_grid = _distance_to_nearest(grid, centers) > a + 1.0 * h
        return np.vstack([guards[keep_guard], grid[keep_grid], outline])

    def _top_surface(self):
        """Vertices (x, y, z) [m] and triangles of the top surface (a height field).

        Caps: the template's triangulation, translated to every lens. Flat: a Delaunay
        triangulation of the rim and flat points, less the triangles inside a rim (all three
        vertices on the same rim). The edge between neighbouring rim vertices is in both (a circle
        through them just inside the rim holds no other point), so the two triangulations meet
        along every rim edge for edge.
        """
        cap, cap_faces, n_rim = self._cap_template()
        centers = self.lens_centers()
        n_lens, n_cap = len(centers), len(cap)
        caps = (cap[None] + np.column_stack([centers, np.zeros(n_lens)])[:, None, :]).reshape(-1, 3)
        faces = [(cap_faces[None] + n_cap * np.arange(n_lens)[:, None, None]).reshape(-1, 3)]

        flat = self._flat_points()
        rim_index = (n_cap * np.arange(n_lens)[:, None] + np.arange(n_cap - n_rim, n_cap)[None]).ravel()
        pts2d = np.vstack([caps[rim_index, :2], flat]) / self.edge_length
        flat_faces = Delaunay(pts2d).simplices
        lens_of = np.concatenate([np.repeat(np.arange(n_lens), n_rim), np.full(len(flat), -1)])
        owner = lens_of[flat_faces]
        inside_rim = (owner[:, 0] >= 0) & (owner[:, 0] == owner[:, 1]) & (owner[:, 0] == owner[:, 2])
        to_global = np.concatenate([rim_index, n_lens * n_cap + np.arange(len(flat))])
        faces.append(to_global[_counter_clockwise(flat_faces[~inside_rim], pts2d)])

        top = np.vstack([caps, np.column_stack([flat, np.zeros(len(flat))])])
        faces = np.vstack(faces)
        # merge coincident points (a rim vertex exactly on a touching neighbour's)
        key = np.round(top[:, :2] / (1e-4 * self.edge_length)).astype(np.int64)
        key -= key.min(0)
        _, first, inverse = np.unique(key[:, 0] * (key[:, 1].max() + 1) + key[:, 1], return_index=True,
                                      return_inverse=True)
        if len(first) < len(top):
            keep = np.sort(first)
            new_index = np.empty(len(first), np.int64)
            new_index[np.argsort(first)] = np.arange(len(first))  # unique group -> position in keep
            faces = new_index[inverse][faces]
            top = top[keep]
            faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
        return top, faces

    def mesh(self) -> trimesh.Trimesh:
        """The sample as one watertight, consistently wound triangle mesh, coordinates in metres."""
        top, f = self._top_surface()

        # directed boundary edges (i → j, counter-clockwise around the top)
        e = np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        n_top = len(top)
        undirected = np.minimum(e[:, 0], e[:, 1]) * n_top + np.maximum(e[:, 0], e[:, 1])  # one int64 per edge
        _, inv, cnt = np.unique(undirected, return_inverse=True, return_counts=True)
        bnd = e[cnt[inv] == 1]

        bverts = np.unique(bnd)
        bot_index = np.full(n_top, -1, np.int64)
        bot_index[bverts] = n_top + np.arange(len(bverts))
        bottom = np.column_stack([top[bverts, :2], np.full(len(bverts), -self.base_thickness)])
        c_idx = n_top + len(bverts)
        x0, y0, x1, y1 = self.slab_bounds()
        centre = [[0.5 * (x0 + x1), 0.5 * (y0 + y1), -self.base_thickness]]

        i, j = bnd[:, 0], bnd[:, 1]
        ib, jb = bot_index[i], bot_index[j]
        walls = np.vstack([np.column_stack([j, i, ib]), np.column_stack([j, ib, jb])])
        fan = np.column_stack([np.full(len(bnd), c_idx), jb, ib])
        vertices = np.vstack([top, bottom, centre])
        faces = np.vstack([f, walls, fan])
        m = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
        m.remove_unreferenced_vertices()
        return m

    def max_facet_error(self, mesh: trimesh.Trimesh | None = None) -> float:
        """Upper estimate [m] of the *vertical* gap |mesh − analytic height| on the caps.

        An inscribed planar facet of circumradius r_c deviates from the sphere by at most
        ≈ r_c²/(2R) along its normal, i.e. r_c²/(2R)/n_z vertically (n_z = facet normal's z part).
        Beyond the rim chords the mesh is flat while the cap is not: at most
        z'(a)·a(1 − cos(π/n_rim)) with z'(a) = a/√(R² − a²). The larger of the two is returned.
        """
        mesh = self.mesh() if mesh is None else mesh
        a, R = self.diameter / 2, self.radius_of_curvature
        t = mesh.triangles
        t = t[t[:, :, 2].max(1) > 1e-3 * self.sag]  # cap facets
        la = np.linalg.norm(t[:, 1] - t[:, 2], axis=1)
        lb = np.linalg.norm(t[:, 0] - t[:, 2], axis=1)
        lc = np.linalg.norm(t[:, 0] - t[:, 1], axis=1)
        cr = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        area = 0.5 * np.linalg.norm(cr, axis=1)
        nz = np.abs(cr[:, 2]) / np.maximum(2 * area, 1e-300)
        rc = la * lb * lc / (4 * np.maximum(area, 1e-300))
        facet = float((rc ** 2 / (2 * R) / np.maximum(nz, 1e-6)).max())
        n_rim = max(12, int(np.ceil(2 * np.pi * a / self.edge_length)))
        slope = a / np.sqrt(max(R * R - a * a, 1e-300))
        rim = slope * a * (1 - np.cos(np.pi / n_rim))
        return max(facet, rim)

    def heightmap(self, shape=(256, 256), extent=(20e-6, 20e-6), *, center=None, pixel_size=None,
                  mesh: trimesh.Trimesh | None = None) -> HeightMap:
        """Height map by ray casting the mesh on a grid (default 20 µm × 20 µm centred on the array).

        ``extent`` [m] or ``pixel_size`` [m] sets the grid; see :func:`afmsim.samples.raycast.pixel_grid`.
        Rays outside the slab read the flat-top height 0.
        """
        mesh = self.mesh() if mesh is None else mesh
        if pixel_size is not None:
            extent = None
        return mesh_to_heightmap(mesh, shape, extent, pixel_size=pixel_size,
                                 center=self.center if center is None else center, background=0.0)


def microlens_mesh(**params) -> trimesh.Trimesh:
    """Watertight mesh (metres) of a :class:`MicroLensArray` built from keyword parameters."""
    return MicroLensArray(**params).mesh()


def microlens_heightmap(shape=(256, 256), extent=(20e-6, 20e-6), *, center=None, pixel_size=None,
                        **params) -> HeightMap:
    """Ray-cast height map of a :class:`MicroLensArray` built from keyword parameters."""
    return MicroLensArray(**params).heightmap(shape, extent, center=center, pixel_size=pixel_size)


def regenerate_default_mesh(path: str = DEFAULT_MESH_PATH, **params) -> str:
    """(Re)write the default micro-lens mesh file (binary PLY, coordinates in **micrometres**).

    ``params`` override :class:`MicroLensArray` defaults. Returns the path written.
    """
    m = MicroLensArray(**params).mesh()
    m = m.copy()
    m.apply_scale(1.0 / DEFAULT_MESH_UNIT)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    m.export(path)
    return path


def load_default_mesh() -> trimesh.Trimesh:
    """The stored default mesh (``samples/microlens_array.ply``) in metres.

    If the file is absent (e.g. a non-editable install without the repo's ``samples/`` folder),
    the same mesh is built in memory (~0.3 s) instead."""
    from .loaders import load_mesh

    if not os.path.isfile(DEFAULT_MESH_PATH):
        return MicroLensArray().mesh()
    return load_mesh(DEFAULT_MESH_PATH, unit=DEFAULT_MESH_UNIT)
