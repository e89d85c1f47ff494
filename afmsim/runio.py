"""Run folders: every run writes into its own folder, atomically, with a manifest.

A run is assembled in a hidden temporary folder beside its destination and renamed into place
only when everything has been written, so an interrupted or failed run leaves no half-written
output. ``manifest.json`` records the configuration, seed, package versions and git revision.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path

import numpy as np

import afmsim

__all__ = ["run_folder", "default_run_dir", "write_json", "versions", "git_revision"]

_PACKAGES = ("numpy", "scipy", "numba", "scikit-image", "opencv-python-headless", "trimesh", "pyvista", "vtk",
             "matplotlib", "pydantic", "gwyfile")


def versions() -> dict:
    """Versions of Python, afmsim and its main dependencies."""
    found = {"python": platform.python_version(), "afmsim": afmsim.__version__}
    for name in _PACKAGES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = None
    return found


def git_revision() -> dict:
    """The git commit of the afmsim source tree and whether it had uncommitted changes."""
    root = Path(afmsim.__file__).resolve().parents[1]
    def git(*args):
        return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10)
    try:
        head = git("rev-parse", "HEAD")
        if head.returncode != 0:
            return {"commit": None, "dirty": None}
        dirty = bool(git("status", "--porcelain", "--untracked-files=no").stdout.strip())
        return {"commit": head.stdout.strip(), "dirty": dirty}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def write_json(path, data) -> None:
    """Write JSON (numpy values converted, non-finite floats as null) atomically."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w") as handle:
        json.dump(_jsonable(data), handle, indent=2)
        handle.write("\n")
    os.replace(tmp, path)


def default_run_dir(kind: str, name: str, base="outputs") -> Path:
    """``outputs/<kind>-<name>-<UTC timestamp>``: a fresh folder name for each run."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    return Path(base) / f"{kind}-{name}-{stamp}"


@contextmanager
def run_folder(destination, *, config: dict, seed: int, command: str):
    """Yield a temporary folder to write a run into; on success move it to ``destination``.

    ``destination`` must not exist yet. ``manifest.json`` (config, seed, versions, git revision,
    command, start and end times) is written last, then the folder is renamed into place. On any
    exception the temporary folder is removed and nothing appears at ``destination``.
    """
    destination = Path(destination)
    if destination.exists():
        raise FileExistsError(f"output folder {destination} already exists: choose another --out or remove it")
    destination.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=destination.parent, prefix=f".{destination.name}.partial-"))
    started = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    try:
        yield staging
        write_json(staging / "manifest.json", {
            "command": command, "config": config, "seed": seed, "versions": versions(),
            "git": git_revision(), "platform": platform.platform(), "argv": sys.argv,
            "started_utc": started, "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "units": "SI (m, V, s) unless a key names another unit",
        })
        os.replace(staging, destination)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
