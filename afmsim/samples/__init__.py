"""Samples: topographies as :class:`HeightMap` (metres), built analytically or from meshes.

* :mod:`.heightmap` — the grid carrier :class:`HeightMap`.
* :mod:`.microlens` — PDMS spherical micro-lens array as a watertight trimesh mesh
  (:class:`MicroLensArray`), turned into height maps by ray casting.
* :mod:`.grating` — HS-500MG silicon grating, analytic (:func:`grating_heightmap`).
* :mod:`.raycast` — mesh → height map by vertical ray casting (:func:`mesh_to_heightmap`).
* :mod:`.loaders` — mesh / .npy / .tiff import and export, :func:`sample_from_spec`.
"""

from .heightmap import HeightMap
from .raycast import mesh_to_heightmap, pixel_grid
from .microlens import (
    DEFAULT_MESH_PATH,
    MicroLensArray,
    load_default_mesh,
    microlens_heightmap,
    microlens_mesh,
    regenerate_default_mesh,
)
from .grating import grating_heightmap, grating_profile
from .loaders import (
    load_heightmap,
    load_mesh,
    mesh_file_to_heightmap,
    sample_from_spec,
    save_heightmap,
    save_mesh,
)

__all__ = [
    "HeightMap",
    "mesh_to_heightmap",
    "pixel_grid",
    "MicroLensArray",
    "microlens_mesh",
    "microlens_heightmap",
    "DEFAULT_MESH_PATH",
    "regenerate_default_mesh",
    "load_default_mesh",
    "grating_heightmap",
    "grating_profile",
    "load_mesh",
    "save_mesh",
    "mesh_file_to_heightmap",
    "load_heightmap",
    "save_heightmap",
    "sample_from_spec",
]
