"""Memory a scenario run needs, estimated before anything is allocated, and the guard that refuses it.

:func:`estimate_memory` counts the arrays that dominate a run's peak, phase by phase, without
building any of them. Sizes (all float64, 8 bytes):

* ``N`` trajectory samples: approach (``numerics.approach_s`` at the scan's sample rate) plus
  ``scan.lines × 2 × scan.pixels × numerics.samples_per_pixel`` (see
  :func:`afmsim.scan.raster_trajectory`);
* ``G`` sample-grid cells: the scan window plus margin at ``1/numerics.sample_oversampling`` of
  the finer image pixel (:func:`afmsim.experiment._sample_grid`), or the cells of a height-map file;
* ``M`` identification samples: one triangle cycle, ``identification.sample_rate_hz / frequency_hz``;
* ``V`` vertices of the micro-lens mesh (cap area / edge² plus rim and guard rings per lens);
* ``P = scan.pixels × scan.lines`` image pixels; ``n = identification.n_operators``.

Held for the whole run: the trajectory ``t, x, y`` (3N), the true and tip-dilated sample (2G), the
micro-lens mesh with trimesh's caches (≈ 450 B per vertex, measured) and 4 images (trace,
retrace, actual x of each) per controller. On top, the largest of these transient phases:

* *mesh* (micro-lens): building the mesh, ≈ 1000 B per vertex (Delaunay triangulation, point
  lists), plus the lens-centre distance matrix of its flat part (flat points × lenses × 32 B);
* *sample*: ray casting a mesh onto the grid, ≈ 600 B per vertex (triangle copies), 374 B per
  cell for the triangle/pixel candidate pairs (at most 760 MB: the caster works in chunks of
  4·10⁶ pairs) and 2G for its output; a mesh file: ≈ 10 × its size plus the same ray cast; a
  generated grating or a height-map file: 2G while it is built or read and converted;
* *identification*: the stage model on M samples (≈ 6M) plus the costliest controller fit, per
  sample ``vendor 7, spi 2n+3, diapi 5n+3, iiapi 5n+4, capi 16n`` (operator matrices, design
  matrix and its scaled copies);
* *scan*, per controller: the x drive is held while the y drive is predicted, with per-sample
  costs ``none/ideal 1, vendor 6, spi n+1, diapi n+4, iiapi n+2, capi 9n+1`` (the N × n operator
  matrix and, for CAPI, its lag powers); else the stage model and the Z loop (9N: drives,
  positions, interpolation coordinates, deflection noise);
* *report* (``report=True``): off-screen 3D renders, ≈ 530 B per rendered cell (images, the
  sample grid when there is no mesh, or the mesh's vertices) plus ≈ 360 MB for VTK and its OpenGL context.

The per-sample factors were counted from the code and checked with :mod:`tracemalloc` (the tests
keep the estimate within a factor 2 of a measured run); the Preisach relay state (60 × 60) and
the per-pixel images are small and are left out. Numba kernels allocate no large arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from afmsim.experiment import _sample_grid, scan_geometry
from afmsim.scenario import Scenario, ScenarioError, check_sample_files

__all__ = ["MemoryTerm", "MemoryEstimate", "memory_breakdown", "estimate_memory", "available_memory",
           "check_memory", "preflight", "format_bytes"]

F64 = 8
_LENS_EDGE_M = 150e-9           # afmsim.samples.MicroLensArray.edge_length default
_MESH_HELD_PER_VERTEX = 450     # bytes: trimesh mesh plus the caches ray casting fills
_MESH_BUILD_PER_VERTEX = 1000   # bytes: Delaunay and point lists while the mesh is built
_RAYCAST_PER_VERTEX = 600       # bytes: the ray caster's triangle copies and bounding boxes
_RAYCAST_PER_CELL = 374         # bytes: candidate (triangle, pixel) pairs, ≈ 2 per cell × 190 B
_RAYCAST_CHUNK = 760e6          # bytes: one chunk of 4·10⁶ pairs
_RENDER_PER_CELL = 530          # bytes: pyvista/VTK surface of one cell, measured
_RENDER_CONTEXT = 360e6         # bytes: VTK libraries and the off-screen OpenGL (llvmpipe) context, measured
_FIT_FACTOR = {"none": (0, 0), "ideal": (0, 0), "vendor": (0, 7), "spi": (2, 3), "diapi": (5, 3),
               "iiapi": (5, 4), "capi": (16, 0)}          # (per operator, constant) float64 per sample
_PREDICT_FACTOR = {"none": (0, 1), "ideal": (0, 1), "vendor": (0, 6), "spi": (1, 1), "diapi": (1, 4),
                   "iiapi": (1, 2), "capi": (9, 1)}


@dataclass(frozen=True)
class MemoryTerm:
    """One family of arrays: what it is, the scenario fields that size it, bytes, how to shrink it."""

    label: str
    fields: str
    bytes: int
    hint: str


@dataclass(frozen=True)
class MemoryEstimate:
    """Terms held for the whole run and the transient terms of each phase; bytes."""

    held: tuple[MemoryTerm, ...]
    phases: dict = field(default_factory=dict)   # phase name -> tuple[MemoryTerm, ...]

    @property
    def peak_phase(self) -> str:
        """The phase whose transient arrays are largest."""
        return max(self.phases, key=lambda name: sum(t.bytes for t in self.phases[name]))

    @property
    def total(self) -> int:
        """Estimated peak: everything held plus the largest phase, bytes."""
        return sum(t.bytes for t in self.held) + sum(t.bytes for t in self.phases[self.peak_phase])

    def dominant(self) -> MemoryTerm:
        """The largest single term at the peak: what to shrink first."""
        return max((*self.held, *self.phases[self.peak_phase]), key=lambda t: t.bytes)


def format_bytes(n: float) -> str:
    """``n`` bytes as ``"61.2 GiB"`` (binary units)."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    raise AssertionError("unreachable")


def _trajectory_samples(scenario: Scenario) -> tuple[int, int]:
    """(approach samples, frame samples) of the raster trajectory (afmsim.scan.raster_trajectory)."""
    geometry = scan_geometry(scenario)
    approach = max(round(geometry.approach_s * geometry.sample_rate_hz), 2)
    return approach, geometry.lines * 2 * geometry.pixels * geometry.samples_per_pixel


def _grid(scenario: Scenario) -> tuple[int, float, float]:
    """(cells, width m, height m) of the simulated sample grid."""
    (rows, cols), (pixel, _), _ = _sample_grid(scan_geometry(scenario), scenario.numerics.sample_oversampling)
    return rows * cols, cols * pixel, rows * pixel


def _heightmap_cells(path: Path) -> int:
    """Cells of a height-map file from its header; 0 when unreadable (the loader reports that)."""
    import numpy as np

    try:
        if path.suffix.lower() == ".npy":
            return math.prod(np.load(path, mmap_mode="r", allow_pickle=False).shape)
        import tifffile

        with tifffile.TiffFile(path) as tif:
            return math.prod(tif.series[0].shape)
    except Exception:  # noqa: BLE001 - any unreadable file: the loader gives the one-line error at run time
        return 0


def _lens_mesh(scenario: Scenario, width: float, height: float) -> tuple[int, int, int]:
    """(vertices, lenses, flat-grid points) of the micro-lens mesh afmsim.experiment.build_sample makes."""
    spec, um, h = scenario.sample, 1e-6, _LENS_EDGE_M
    pitch = spec.pitch_um * um
    counts = [math.ceil(e / pitch) // 2 * 2 + 1 for e in (width, height)]
    lenses = counts[0] * counts[1]
    a, sag = spec.diameter_um * um / 2, spec.sag_um * um
    radius = (a * a + sag * sag) / (2 * sag)
    per_lens = max(2 * math.pi * radius * sag / h ** 2 + 4 * math.pi * a / h, 40)
    flat_step = max(4 * h, min(pitch / 4, 1e-6))
    flat = math.prod(math.ceil((c * pitch + 2 * a) / flat_step) for c in counts)
    return int(lenses * per_lens + flat), lenses, flat


def memory_breakdown(scenario: Scenario, *, report: bool = True) -> MemoryEstimate:
    """Itemised estimate of a run's memory (see the module docstring); nothing is allocated."""
    approach, frame = _trajectory_samples(scenario)
    n_samples = approach + frame
    cells, width, height = _grid(scenario)
    pixels = scenario.scan.pixels * scenario.scan.lines
    names = list(dict.fromkeys(scenario.controllers))
    n_ops = scenario.identification.n_operators
    ident = scenario.identification
    m_samples = round(ident.sample_rate_hz / ident.frequency_hz) + 1
    kind = scenario.sample.kind
    if kind == "heightmap":
        cells = _heightmap_cells(scenario.sample.path)

    reduce_scan = "reduce scan.pixels/lines or numerics.samples_per_pixel"
    reduce_grid = "reduce scan.pixels/lines or numerics.sample_oversampling"
    traj_fields = "scan.pixels × scan.lines × numerics.samples_per_pixel"
    if approach > frame:
        traj_fields, reduce_scan = "numerics.approach_s × scan rate", "reduce numerics.approach_s or scan.line_rate_hz"
    grid_fields = "scan.pixels × scan.lines (sample grid)"
    held = [MemoryTerm("trajectory t, x, y", traj_fields, 3 * F64 * n_samples, reduce_scan),
            MemoryTerm("true and dilated sample", grid_fields, 2 * F64 * cells, reduce_grid),
            MemoryTerm("images", "scan.pixels × scan.lines", 4 * F64 * pixels * len(names),
                       "reduce scan.pixels/lines")]

    phases = {}
    vertices = 0
    raycast = int(min(_RAYCAST_PER_CELL * cells, _RAYCAST_CHUNK) + 2 * F64 * cells)
    if kind == "microlens":
        vertices, lenses, flat = _lens_mesh(scenario, width, height)
        lens_fields = "sample.diameter_um/sag_um/pitch_um"
        lens_hint = "use fewer, smaller lenses (sample.diameter_um, sag_um, pitch_um) or a smaller scan.size_um"
        held.append(MemoryTerm("micro-lens mesh", lens_fields, _MESH_HELD_PER_VERTEX * vertices, lens_hint))
        phases["mesh"] = (MemoryTerm("mesh construction", lens_fields, _MESH_BUILD_PER_VERTEX * vertices, lens_hint),
                          MemoryTerm("flat-part distance matrix", "sample.pitch_um", 32 * flat * lenses,
                                     "raise sample.pitch_um or reduce scan.size_um"))
        phases["sample"] = (MemoryTerm("ray casting", grid_fields, _RAYCAST_PER_VERTEX * vertices + raycast,
                                       reduce_grid),)
    elif kind == "mesh":
        size = scenario.sample.path.stat().st_size if scenario.sample.path.is_file() else 0
        phases["sample"] = (MemoryTerm("mesh file", "sample.path", 10 * size, "use a coarser mesh"),
                            MemoryTerm("ray casting", grid_fields, raycast, reduce_grid))
    else:
        phases["sample"] = (MemoryTerm("sample construction", grid_fields, 2 * F64 * cells, reduce_grid),)

    def per_sample(table, name):
        per_op, const = table.get(name, (0, 0))
        return per_op * n_ops + const

    fit = max(per_sample(_FIT_FACTOR, c) for c in names)
    predict = max(per_sample(_PREDICT_FACTOR, c) for c in names)
    ident_fields = "identification.sample_rate_hz / frequency_hz"
    scan_fields, scan_hint = traj_fields, reduce_scan
    if predict + 1 > 9:  # the controllers' operator matrices dominate the stage/Z-loop arrays
        scan_fields = f"{traj_fields} × controller operators"
        scan_hint = f"{reduce_scan}, or lower identification.n_operators"
    phases.update({
        "identification": (MemoryTerm("identification stage model and fit", ident_fields, F64 * (6 + fit) * m_samples,
                                      "lower identification.sample_rate_hz or raise frequency_hz"),),
        "scan": (MemoryTerm("controller drives and stage/Z-loop arrays", scan_fields,
                            F64 * max(1 + predict, 9) * n_samples, scan_hint),),
    })
    if report:
        rendered = max(pixels, vertices if kind == "microlens" else cells)
        phases["report"] = (MemoryTerm("3D renders", grid_fields, int(_RENDER_CONTEXT + _RENDER_PER_CELL * rendered),
                                       reduce_grid),)
    return MemoryEstimate(tuple(held), phases)


def estimate_memory(scenario: Scenario, *, report: bool = True) -> int:
    """Estimated peak memory of running ``scenario`` (``afmsim run``; ``report=False``: only
    :func:`afmsim.experiment.run_scenario`), bytes."""
    return memory_breakdown(scenario, report=report).total


def _cgroup_headroom() -> int | None:
    """Bytes left under this process's cgroup memory limit (v2 or v1), or None if unlimited/unknown."""
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            limit = Path(limit_file).read_text().strip()
            usage = int(Path(usage_file).read_text().strip())
        except (OSError, ValueError):
            continue
        if limit.isdigit() and int(limit) < 1 << 60:
            return max(int(limit) - usage, 0)
    return None


def available_memory() -> int | None:
    """Memory available to a new allocation now, bytes: psutil's (or ``/proc/meminfo``'s)
    MemAvailable, capped by the cgroup limit; None when neither can be read."""
    found = None
    try:
        import psutil

        found = int(psutil.virtual_memory().available)
    except ImportError:
        try:
            with open("/proc/meminfo") as meminfo:
                for line in meminfo:
                    if line.startswith("MemAvailable:"):
                        found = int(line.split()[1]) * 1024
        except (OSError, ValueError, IndexError):
            found = None
    headroom = _cgroup_headroom()
    if headroom is not None:
        found = headroom if found is None else min(found, headroom)
    return found


def check_memory(scenario: Scenario, *, report: bool = True, available: int | None = None) -> tuple[int, int | None]:
    """Refuse a scenario whose arrays would not fit: raises :class:`~afmsim.scenario.ScenarioError`
    (one line with the estimate and what to reduce). Returns ``(needed, available)`` in bytes;
    ``available`` defaults to :func:`available_memory` (None: unknown, never refused)."""
    breakdown = memory_breakdown(scenario, report=report)
    needed = breakdown.total
    available = available_memory() if available is None else available
    if available is not None and needed > available:
        top = breakdown.dominant()
        raise ScenarioError(f"{top.fields}: needs ≈ {format_bytes(needed)}, {format_bytes(available)} available "
                            f"(largest: {top.label}, {format_bytes(top.bytes)}) — {top.hint}")
    return needed, available


def preflight(scenario: Scenario, *, report: bool = True) -> tuple[int, int | None]:
    """Everything checked before a run allocates or writes anything: the sample file is readable
    (:func:`~afmsim.scenario.check_sample_files`) and the arrays fit (:func:`check_memory`).
    Raises :class:`~afmsim.scenario.ScenarioError`; returns ``(needed, available)`` bytes."""
    check_sample_files(scenario)
    return check_memory(scenario, report=report)
