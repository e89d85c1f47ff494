"""Atomic run folders (issue 6): a run that fails, is interrupted or is killed leaves no folder
that looks complete; a killed run's hidden staging folder is removed by the next run."""

import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from afmsim import runio
from afmsim.runio import remove_stale_staging, replace_atomically, run_folder, write_json

ROOT = Path(__file__).resolve().parents[1]


def _start_quick_run(out: Path) -> subprocess.Popen:
    # SIGINT restored to its default so that Python installs its KeyboardInterrupt handler even
    # when this test runs as a background job (which starts with SIGINT ignored)
    command = [sys.executable, "-m", "afmsim", "run", "scenarios/quick.yaml", "--out", str(out), "--quiet"]
    return subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _wait_for_staging(out: Path, proc: subprocess.Popen) -> Path:
    """The hidden staging folder of the run writing ``out``, once it exists (the run is then mid-way)."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        found = list(out.parent.glob(f".{out.name}.partial-*"))
        if found:
            return found[0]
        if proc.poll() is not None:
            pytest.fail(f"run ended before its staging folder appeared: {proc.communicate()}")
        time.sleep(0.01)
    proc.kill()
    pytest.fail("no staging folder after 120 s")


def test_sigkilled_run_leaves_nothing_that_looks_complete_and_the_next_run_cleans_up(tmp_path):
    out = tmp_path / "o"
    proc = _start_quick_run(out)
    staging = _wait_for_staging(out, proc)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert not out.exists()
    assert list(tmp_path.rglob("manifest.json")) == []
    assert staging.is_dir()                   # the dying process cannot clean up ...
    with run_folder(tmp_path / "next", config={}, seed=0, command="test"):
        pass
    assert not staging.exists()               # ... the next run into the same folder does
    assert sorted(p.name for p in tmp_path.iterdir()) == ["next"]


def test_interrupted_run_removes_its_staging_folder(tmp_path):
    out = tmp_path / "o"
    proc = _start_quick_run(out)
    _wait_for_staging(out, proc)
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    assert proc.returncode != 0
    assert list(tmp_path.iterdir()) == []


def test_failed_run_leaves_nothing(tmp_path):
    for error in (ValueError("bad"), KeyboardInterrupt()):
        with pytest.raises(type(error)):
            with run_folder(tmp_path / "o", config={}, seed=0, command="test") as staging:
                (staging / "half.txt").write_text("half")
                raise error
        assert list(tmp_path.iterdir()) == []


def test_successful_run_is_renamed_into_place_with_its_manifest(tmp_path):
    with run_folder(tmp_path / "o", config={"a": 1}, seed=5, command="test") as staging:
        assert staging.parent == tmp_path and staging.name.startswith(".o.partial-")
        (staging / "result.txt").write_text("done")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["manifest.json", "result.txt"]
    manifest = json.loads((tmp_path / "o" / "manifest.json").read_text())
    assert manifest["config"] == {"a": 1} and manifest["seed"] == 5 and manifest["command"] == "test"


def test_existing_destination_is_refused(tmp_path):
    (tmp_path / "o").mkdir()
    with pytest.raises(FileExistsError, match="already exists"):
        with run_folder(tmp_path / "o", config={}, seed=0, command="test"):
            pass
    assert [p.name for p in tmp_path.iterdir()] == ["o"]


def test_stale_cleanup_spares_live_runs_and_foreign_folders(tmp_path):
    foreign = tmp_path / ".x.partial-foreign"           # no lock file: not ours, or about to be renamed
    foreign.mkdir()
    with run_folder(tmp_path / "live", config={}, seed=0, command="test") as staging:
        assert remove_stale_staging(tmp_path) == []
        assert staging.is_dir() and foreign.is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == [".x.partial-foreign", "live"]


def test_a_staging_folder_is_locked_before_it_is_named_partial(tmp_path, monkeypatch):
    """Every ``.partial-`` folder has its held ``.lock`` from its first moment: at the instant it
    appears under that name (its rename) a cleaner cannot remove it, and a run killed at that
    instant (CI under load hit the window between the folder's mkdir and its lock) is cleaned up
    by the next one."""
    seen = []
    rename = os.rename

    def watching_rename(src, dst):
        rename(src, dst)
        seen.append((Path(dst).name, (Path(dst) / ".lock").is_file(), remove_stale_staging(tmp_path)))

    monkeypatch.setattr(runio.os, "rename", watching_rename)
    with run_folder(tmp_path / "o", config={}, seed=0, command="test"):
        pass
    assert len(seen) == 1 and seen[0][0].startswith(".o.partial-") and seen[0][1:] == (True, [])
    # a run that died right after making its (locked) prep folder: the next run removes it
    dead = tmp_path / ".p.prep-deadbeef"
    dead.mkdir()
    (dead / ".lock").touch()
    with run_folder(tmp_path / "next", config={}, seed=0, command="test"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["next", "o"]


def test_a_ctrl_c_while_the_staging_folder_is_made_leaves_nothing(tmp_path, monkeypatch):
    """SIGINT delivered as the staging folder has just been made, before ``run_folder`` holds its
    name (the other window CI under load hit): the interrupt is held back until the run owns the
    folder, then raised, and the folder is removed."""
    make = runio._new_staging

    def interrupted(destination):
        made = make(destination)
        signal.raise_signal(signal.SIGINT)  # to this thread: handled at the next bytecode, before `made` is returned
        return made

    monkeypatch.setattr(runio, "_new_staging", interrupted)
    # Python's own Ctrl-C handler, as in a terminal: a test process started in the background by a
    # non-interactive shell inherits SIGINT ignored, and then there is no Ctrl-C to hold back
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            with run_folder(tmp_path / "o", config={}, seed=0, command="test"):
                pytest.fail("the run body must not start after a Ctrl-C")
        assert list(tmp_path.iterdir()) == []
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize("umask, folder_mode, file_mode", [(0o022, 0o755, 0o644), (0o002, 0o775, 0o664),
                                                           (0o077, 0o700, 0o600)])
def test_run_folders_and_their_files_follow_the_umask(tmp_path, umask, folder_mode, file_mode):
    previous = os.umask(umask)
    try:
        with run_folder(tmp_path / "o", config={}, seed=0, command="test") as staging:
            write_json(staging / "scores.json", {"a": 1})
            (staging / "plain.txt").write_text("written by open()")
            replace_atomically(staging / "table.csv", lambda tmp: Path(tmp).write_text("a,b\n"))   # sweep tables
        write_json(tmp_path / "beside.json", [1, 2])
    finally:
        os.umask(previous)
    def mode(path):
        return stat.S_IMODE(path.stat().st_mode)
    assert mode(tmp_path / "o") == folder_mode
    assert {p.name: mode(p) for p in (tmp_path / "o").iterdir()} == {
        "manifest.json": file_mode, "scores.json": file_mode, "plain.txt": file_mode, "table.csv": file_mode}
    assert mode(tmp_path / "beside.json") == file_mode
    assert sorted(p.name for p in tmp_path.iterdir()) == ["beside.json", "o"]     # no temporary left behind
