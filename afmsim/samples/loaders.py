"""Sample import/export: meshes (STL/OBJ/PLY/… via trimesh) and height maps (.npy, .tif/.tiff).

Files carry no reliable length unit, so every loader takes the unit explicitly and converts to
metres: ``unit`` = metres per file unit for meshes (default 1e-6: micrometres), ``pixel_size``
[m] and ``z_scale`` (metres per stored height value, default 1.0 = the file holds metres) for
height maps. Bad input raises ``ValueError`` naming the file and the problem.
"""

from __future__ import annotations

import os

import numpy as np
import trimesh

from .heightmap import HeightMap
from .raycast import mesh_to_heightmap

__all__ = [
    "load_mesh",
    "mesh_file_to_heightmap",
    "load_heightmap",
    "save_heightmap",
    "save_mesh",
    "sample_from_spec",
]

MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")
MAP_SUFFIXES = (".npy", ".tif", ".tiff")


def _existing(path) -> str:
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"{path!r}: no such file")
    return path


def load_mesh(path, *, unit: float = 1e-6) -> trimesh.Trimesh:
    """Read a triangle mesh (any format trimesh reads) and return it in metres.

    Parameters
    ----------
    path : str or PathLike
        Mesh file (STL, OBJ, PLY, OFF, GLB…). Multi-body scenes are concatenated into one mesh.
    unit : float
        Metres per file unit (1e-6: file in µm; 1e-9: nm; 1.0: m). Vertices are merged in file
        units (trimesh's merge tolerance is absolute), then scaled.
    """
    path = _existing(path)
    if not unit > 0:
        raise ValueError(f"unit must be > 0 (metres per file unit), got {unit}")
    try:
        loaded = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises a zoo of types on garbage
        raise ValueError(f"{path!r}: not a readable mesh ({type(exc).__name__}: {exc})") from exc
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
        loaded = trimesh.util.concatenate(geoms) if geoms else None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ValueError(f"{path!r}: file holds no triangles")
    if not np.all(np.isfinite(loaded.vertices)):
        raise ValueError(f"{path!r}: mesh has non-finite vertex coordinates")
    mesh = loaded.copy()
    mesh.apply_scale(unit)
    return mesh


def save_mesh(mesh: trimesh.Trimesh, path, *, unit: float = 1e-6) -> str:
    """Write ``mesh`` (metres) to ``path`` in file units of ``unit`` metres (format from suffix)."""
    m = mesh.copy()
    m.apply_scale(1.0 / unit)
    m.export(os.fspath(path))
    return os.fspath(path)


def mesh_file_to_heightmap(path, shape=(256, 256), extent=None, *, unit: float = 1e-6, **grid) -> HeightMap:
    """Load a mesh file (see :func:`load_mesh`) and ray-cast it (see
    :func:`afmsim.samples.raycast.mesh_to_heightmap`; ``grid`` takes pixel_size/origin/center/
    background/engine)."""
    return mesh_to_heightmap(load_mesh(path, unit=unit), shape, extent, **grid)


def load_heightmap(path, pixel_size, *, origin=(0.0, 0.0), z_scale: float = 1.0) -> HeightMap:
    """Read a 2-D height array from ``.npy`` or ``.tif``/``.tiff``.

    Parameters
    ----------
    path : str or PathLike
    pixel_size : float or (float, float)
        Pixel pitch (dx, dy) [m]; a scalar means square pixels.
    origin : (float, float)
        Centre of pixel [0, 0] [m].
    z_scale : float
        Metres per stored value (1.0: file in metres; 1e-9: nm).

    Singleton leading/trailing axes (e.g. a (1, ny, nx) TIFF page stack of one) are squeezed;
    anything else that is not 2-D, not real numeric, or not finite is rejected.
    """
    path = _existing(path)
    suffix = os.path.splitext(path)[1].lower()
    try:
        if suffix == ".npy":
            arr = np.load(path, allow_pickle=False)
        elif suffix in (".tif", ".tiff"):
            import tifffile

            arr = tifffile.imread(path)
        else:
            raise ValueError(f"{path!r}: unsupported height-map suffix {suffix!r}; use one of {MAP_SUFFIXES}")
    except ValueError as exc:
        if str(exc).startswith(repr(path)):
            raise
        raise ValueError(f"{path!r}: cannot read as {suffix} ({exc})") from exc
    except Exception as exc:
        raise ValueError(f"{path!r}: cannot read as {suffix} ({type(exc).__name__}: {exc})") from exc
    arr = np.asarray(arr)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{path!r}: height data must be real numbers, got dtype {arr.dtype}")
    if arr.ndim > 2:
        arr = arr.squeeze()
    if arr.ndim != 2:
        raise ValueError(f"{path!r}: height map must be a 2-D array, got shape {arr.shape}"
                         + (" (RGB/multi-channel image?)" if arr.ndim == 3 else ""))
    if min(arr.shape) < 2:
        raise ValueError(f"{path!r}: height map must be at least 2×2, got shape {arr.shape}")
    z = arr.astype(np.float64) * float(z_scale)
    if not np.all(np.isfinite(z)):
        raise ValueError(f"{path!r}: height map contains NaN or inf")
    ps = np.broadcast_to(np.asarray(pixel_size, float), (2,))
    if not np.all(ps > 0):
        raise ValueError(f"pixel_size must be > 0, got {pixel_size}")
    return HeightMap(z, (float(ps[0]), float(ps[1])), tuple(origin))


def save_heightmap(hm: HeightMap, path, *, z_scale: float = 1.0) -> str:
    """Write ``hm.z / z_scale`` to ``.npy`` or ``.tif``/``.tiff`` (float64). The grid (pixel size,
    origin) is not stored: pass it again to :func:`load_heightmap`."""
    path = os.fspath(path)
    suffix = os.path.splitext(path)[1].lower()
    data = hm.z / float(z_scale)
    if suffix == ".npy":
        np.save(path, data)
    elif suffix in (".tif", ".tiff"):
        import tifffile

        tifffile.imwrite(path, data)
    else:
        raise ValueError(f"{path!r}: unsupported height-map suffix {suffix!r}; use one of {MAP_SUFFIXES}")
    return path


def sample_from_spec(kind: str, shape=(256, 256), extent=(20e-6, 20e-6), **params) -> HeightMap:
    """One entry point for every sample kind; returns a :class:`HeightMap` in metres.

    kind : {"microlens", "grating", "mesh", "heightmap"}
        * ``"microlens"``: ``params`` → :class:`~afmsim.samples.microlens.MicroLensArray` fields,
          plus grid keys ``center``/``pixel_size``; ray-cast on ``shape``/``extent``.
        * ``"grating"``: ``params`` → :func:`~afmsim.samples.grating.grating_heightmap`.
        * ``"mesh"``: ``path`` (+ ``unit``, grid keys) → :func:`mesh_file_to_heightmap`;
          ``extent=None`` covers the mesh's bounding box.
        * ``"heightmap"``: ``path``, ``pixel_size`` (+ ``origin``, ``z_scale``) →
          :func:`load_heightmap`; ``shape``/``extent`` are ignored (the file sets them).
    """
    if kind == "microlens":
        from .microlens import MicroLensArray

        grid = {k: params.pop(k) for k in ("center", "pixel_size") if k in params}
        try:
            lens = MicroLensArray(**params)
        except TypeError as exc:
            raise ValueError(f"bad micro-lens parameter: {exc}") from exc
        return lens.heightmap(shape, extent, **grid)
    if kind == "grating":
        from .grating import grating_heightmap

        try:
            return grating_heightmap(shape, extent, **params)
        except TypeError as exc:
            raise ValueError(f"bad grating parameter: {exc}") from exc
    if kind == "mesh":
        if "path" not in params:
            raise ValueError("kind='mesh' needs path=")
        return mesh_file_to_heightmap(params.pop("path"), shape, extent, **params)
    if kind == "heightmap":
        if "path" not in params or "pixel_size" not in params:
            raise ValueError("kind='heightmap' needs path= and pixel_size=")
        return load_heightmap(params.pop("path"), params.pop("pixel_size"), **params)
    raise ValueError(f"kind must be 'microlens', 'grating', 'mesh' or 'heightmap', got {kind!r}")
