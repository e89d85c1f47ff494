"""Run folders: every run writes into its own folder, atomically, with a manifest.

A run is assembled in a hidden staging folder beside its destination, ``.NAME.partial-XXXXXXXX``,
and renamed into place (one ``os.replace``) only when everything has been written, ``manifest.json``
last; so a folder named ``NAME`` is always complete, and a run that fails, or is interrupted by
Ctrl-C (SIGINT → ``KeyboardInterrupt``), removes its staging folder and leaves nothing behind.

A process killed outright (SIGKILL, SIGTERM, power loss) cannot clean up: its hidden
``.partial-`` folder stays. Such a folder never looks complete — it has no ``manifest.json``
(except if the kill lands in the microseconds between writing the manifest and the rename;
treat every ``.partial-`` folder as incomplete whatever it holds). Each staging folder holds a
``.lock`` file that its run keeps ``flock``-ed while it lives (the kernel drops the lock when the
process dies, however it dies); the next :func:`run_folder` into the same parent folder removes
every staging folder whose lock it can take, see :func:`remove_stale_staging`. A staging folder is
locked before it gets its ``.partial-`` name (:func:`_new_staging`), and a Ctrl-C while it is made
is held back until the run owns it, so a run killed or interrupted at any instant leaves no
``.partial-`` folder that the next run cannot remove. Where ``fcntl`` is
missing (Windows) nothing is locked and stale folders are left for the user to delete.

Permissions follow the user's umask, as for any file the user creates (0755/0644 under the
usual umask 022): the staging folder and the JSON files are created with ``os.mkdir``/``os.open``
and mode 0777/0666, not with :mod:`tempfile`, whose 0700/0600 suit a shared temporary folder but
would make every run private.
"""

from __future__ import annotations

import json
import os
import platform
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path

import numpy as np

import afmsim

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

__all__ = ["run_folder", "remove_stale_staging", "default_run_dir", "write_json", "replace_atomically", "versions",
           "git_revision"]

_LOCK = ".lock"

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


def _create_unique(parent: Path, prefix: str, create):
    """``create(parent / (prefix + 8 random hex digits))`` on a fresh name (retried on a clash);
    returns ``(path, what create returned)``."""
    for _ in range(100):
        path = Path(parent) / f"{prefix}{secrets.token_hex(4)}"
        try:
            return path, create(path)
        except FileExistsError:
            continue
    raise FileExistsError(f"no free name {prefix}* in {parent}")


def replace_atomically(path, write) -> Path:
    """Call ``write(temporary_path)`` beside ``path``, then rename it onto ``path`` (no partial file).

    The temporary file is created empty first (mode 0666 less the umask), so the result has the
    permissions of any file the user creates.
    """
    path = Path(path)
    tmp, fd = _create_unique(path.parent, f".{path.name}.",
                             lambda p: os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_json(path, data) -> None:
    """Write JSON (numpy values converted, non-finite floats as null) atomically, permissions per umask."""
    text = json.dumps(_jsonable(data), indent=2) + "\n"
    replace_atomically(path, lambda tmp: Path(tmp).write_text(text))


def default_run_dir(kind: str, name: str, base="outputs") -> Path:
    """``outputs/<kind>-<name>-<UTC timestamp>``: a fresh folder name for each run."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    return Path(base) / f"{kind}-{name}-{stamp}"


def _hold_lock(folder: Path):
    """Create ``folder/.lock`` already locked (flock'ed under a temporary name, then renamed), so a
    cleaner never sees it unlocked while this process lives; returns the descriptor, or None."""
    if fcntl is None:  # pragma: no cover - Windows
        return None
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f"{_LOCK}-")
    fcntl.flock(fd, fcntl.LOCK_EX)
    os.replace(tmp, folder / _LOCK)
    return fd


@contextmanager
def _sigint_deferred():
    """Hold back Ctrl-C (SIGINT) for the duration of the block and raise its ``KeyboardInterrupt``
    after it: a step that must not be cut in two (a folder made but not yet owned) runs whole.
    Only the main thread can set signal handlers, and only Python's default handler is replaced;
    otherwise the block runs as it is."""
    if threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield
        return
    caught = []
    signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if caught:
        raise KeyboardInterrupt


def _new_staging(destination: Path):
    """A locked staging folder for ``destination``: ``(path, lock descriptor or None)``.

    The folder is made and locked under a name no run writes into (``.NAME.prep-XXXXXXXX``) and
    only then renamed to its ``.partial-`` name, so a ``.partial-`` folder has its held ``.lock``
    from its first moment: a run killed at any instant leaves no ``.partial-`` folder that the next
    run cannot tell from a live one (a kill inside the few system calls before the rename leaves a
    hidden ``.prep-`` folder that holds no output; with its ``.lock`` in place, the next run
    removes it)."""
    prep, _ = _create_unique(destination.parent, f".{destination.name}.prep-", lambda p: os.mkdir(p, 0o777))
    lock = None
    try:
        lock = _hold_lock(prep)
        staging = prep.with_name(prep.name.replace(".prep-", ".partial-", 1))
        os.rename(prep, staging)
    except BaseException:
        if lock is not None:
            os.close(lock)
        shutil.rmtree(prep, ignore_errors=True)
        raise
    return staging, lock


def remove_stale_staging(parent) -> list[Path]:
    """Remove the hidden ``.*.partial-*`` staging folders (and ``.*.prep-*`` ones, see
    :func:`_new_staging`) in ``parent`` left by runs that died.

    A folder is removed only when its ``.lock`` can be locked, i.e. no live process holds it; a
    folder without ``.lock`` (a run in its first or last microseconds, or not made by afmsim) is
    left alone. Returns the folders removed.
    """
    removed = []
    if fcntl is None:  # pragma: no cover - Windows
        return removed
    parent = Path(parent)
    for folder in sorted([*parent.glob(".*.partial-*"), *parent.glob(".*.prep-*")]):
        try:
            fd = os.open(folder / _LOCK, os.O_RDONLY)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        shutil.rmtree(folder, ignore_errors=True)
        os.close(fd)
        removed.append(folder)
    return removed


@contextmanager
def run_folder(destination, *, config: dict, seed: int, command: str, extra: dict | None = None):
    """Yield a hidden staging folder to write a run into; on success move it to ``destination``.

    ``destination`` must not exist yet. Stale staging folders of dead runs beside it are removed
    first (:func:`remove_stale_staging`). ``manifest.json`` (config, seed, versions, git revision,
    command, start and end times) is written last, then the folder is renamed into place. On any
    exception, ``KeyboardInterrupt`` included, the staging folder is removed and nothing appears
    at ``destination``. ``extra`` (a dict the caller may fill while the run is written, e.g.
    ``timings``) is added to the manifest as it stands when the block ends.
    """
    destination = Path(destination)
    if destination.exists():
        raise FileExistsError(f"output folder {destination} already exists: choose another --out or remove it")
    destination.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(destination.parent)
    staging = lock = None
    started = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    try:
        with _sigint_deferred():  # a Ctrl-C here lands once `staging` names the folder to remove
            staging, lock = _new_staging(destination)
        yield staging
        write_json(staging / "manifest.json", {
            "command": command, "config": config, "seed": seed, "versions": versions(),
            "git": git_revision(), "platform": platform.platform(), "argv": sys.argv,
            "started_utc": started, "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "units": "SI (m, V, s) unless a key names another unit", **(extra or {}),
        })
        if lock is not None:
            (staging / _LOCK).unlink()  # still held through the descriptor until the rename is done
        os.replace(staging, destination)
    except BaseException:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
        raise
    finally:
        if lock is not None:
            os.close(lock)
