"""Sweeps: expansion is reproducible, Dask results equal serial runs, resume recomputes only what is missing."""

import json
import os
import shutil

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from afmsim.cli import app
from afmsim.experiment import run_scenario
from afmsim.scenario import parse_scenario
from afmsim.sweep import (MAX_RUNS, SweepError, SweepRunError, load_sweep, local_cluster, parse_sweep, result_row,
                          run_sweep)

runner = CliRunner()

TINY = {"name": "tiny", "seed": 1, "experiments": 1, "sample": {"kind": "microlens"},
        "scan": {"size_um": [10.0, 10.0], "offset_um": [2.0, 2.0], "pixels": 32, "lines": 32},
        "controllers": ["none", "spi", "diapi"], "identification": {"range": "scan"}}
SWEEP = {"name": "tiny-grid", "base": {**TINY, "experiments": 2},
         "grid": {"scan.size_um": [[6.0, 6.0], [10.0, 10.0]], "seed": [1, 2]}}


@pytest.fixture(scope="module")
def cluster():
    """A real two-process Dask cluster, built as ``afmsim sweep`` builds its default one."""
    with local_cluster(2) as local:
        yield local


@pytest.fixture(scope="module")
def scheduler(cluster):
    return cluster.scheduler_address


def _worker_environment():
    import dask

    found = {name: os.environ.get(name) for name in ("MALLOC_TRIM_THRESHOLD_", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    return {**found, "profiler": dask.config.get("distributed.worker.profile.enabled")}


def test_default_workers_keep_glibc_adaptive_mmap_one_thread_and_no_profiler(cluster):
    """Dask's MALLOC_TRIM_THRESHOLD_ (which costs the runs ~30 % in page faults) is not passed on, nor
    is the 10 ms stack-sampling profiler; the thread caps are."""
    from dask.distributed import Client

    with Client(cluster) as client:
        environments = client.run(_worker_environment)
    assert len(environments) == 2
    expected = {"MALLOC_TRIM_THRESHOLD_": os.environ.get("MALLOC_TRIM_THRESHOLD_"),  # inherited, not Dask's 65536
                "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1"),
                "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "1"), "profiler": False}
    for environment in environments.values():
        assert environment == expected


@pytest.fixture(scope="module")
def finished(scheduler, tmp_path_factory):
    """The SWEEP run once on the cluster: (sweep, folder, returned table)."""
    sweep = parse_sweep(SWEEP)
    out = tmp_path_factory.mktemp("sweeps") / "tiny"
    return sweep, out, run_sweep(sweep, out, scheduler=scheduler)


def _scores(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in ("run_id", "wall_s") and k not in SWEEP["grid"]}


def test_sweep_table_equals_the_same_runs_done_serially(finished):
    sweep, out, table = finished
    runs = sweep.runs()
    assert list(table["run_id"]) == [run.run_id for run in runs] and len(runs) == 4
    for run, (_, row) in zip(runs, table.iterrows()):
        serial = _scores(result_row(run, run_scenario(run.scenario).metrics(), 0.0))
        columns = list(_scores(row.to_dict()))
        assert set(serial) <= set(columns) and "diapi.nsl2_mean" in serial   # other columns: other runs' scores
        got = row[columns].to_numpy(dtype=float)
        expected = np.array([serial.get(c, np.nan) for c in columns], dtype=float)
        assert np.array_equal(got, expected, equal_nan=True), run.params
        assert row["scan.size_um"] == run.params["scan.size_um"] and row["seed"] == run.params["seed"]
    assert table["diapi.nsl2_std"].notna().all() and (table["wall_s"] > 0).all()


def test_sweep_folder_has_tables_plot_and_manifest(finished):
    sweep, out, table = finished
    for name in ("results.csv", "results.parquet"):
        stored = pd.read_csv(out / name) if name.endswith("csv") else pd.read_parquet(out / name)
        assert list(stored["run_id"]) == list(table["run_id"])
        np.testing.assert_array_equal(stored["spi.nsl2_mean"], table["spi.nsl2_mean"])
        assert [json.loads(v) for v in stored["scan.size_um"]] == list(table["scan.size_um"])
    assert (out / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["runs"] == 4 and sorted(manifest["computed_now"]) == sorted(table["run_id"])
    assert manifest["workers"] == 2 and {"dask", "distributed", "pandas", "numpy"} <= set(manifest["versions"])
    assert json.loads((out / "sweep.json").read_text())["fingerprint"] == sweep.fingerprint()
    assert sorted(p.stem for p in (out / "runs").iterdir()) == sorted(table["run_id"])


def test_resume_recomputes_only_the_missing_run(finished, scheduler, tmp_path):
    sweep, out, table = finished
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    missing = table["run_id"][2]
    (copy / "runs" / f"{missing}.json").unlink()
    (copy / "results.csv").unlink()
    kept = {p.name: p.stat().st_mtime_ns for p in (copy / "runs").iterdir()}
    calls = []
    resumed = run_sweep(sweep, copy, scheduler=scheduler, resume=True, progress=lambda *a: calls.append(a))
    manifest = json.loads((copy / "manifest.json").read_text())
    assert manifest["computed_now"] == [missing] and manifest["resumed"] == 3
    assert {p.name: p.stat().st_mtime_ns for p in (copy / "runs").iterdir() if p.name in kept} == kept
    assert calls[0] == (3, 4, "resumed") and calls[-1][:2] == (4, 4)
    np.testing.assert_array_equal(resumed["diapi.nsl2_mean"], table["diapi.nsl2_mean"])
    assert (copy / "results.csv").exists()


def test_an_interrupted_sweep_keeps_its_finished_runs_and_resumes(scheduler, tmp_path):
    sweep = parse_sweep({"name": "ctrl-c", "base": TINY, "grid": {"seed": [5, 6, 7]}})
    out = tmp_path / "sweep"

    def interrupt_after_first(done, total, label):
        if label != "resumed":
            raise KeyboardInterrupt                                  # as Ctrl-C would, after one checkpoint

    with pytest.raises(KeyboardInterrupt):
        run_sweep(sweep, out, scheduler=scheduler, progress=interrupt_after_first)
    assert len(list((out / "runs").iterdir())) == 1
    assert not (out / "manifest.json").exists() and not (out / "results.parquet").exists()
    table = run_sweep(sweep, out, scheduler=scheduler, resume=True)
    assert len(json.loads((out / "manifest.json").read_text())["computed_now"]) == 2
    assert list(table["seed"]) == [5, 6, 7] and table["spi.nsl2_mean"].notna().all()


def test_existing_or_foreign_folders_are_refused(finished, scheduler, tmp_path):
    sweep, out, _ = finished
    with pytest.raises(FileExistsError, match="already exists"):
        run_sweep(sweep, out, scheduler=scheduler)
    other = parse_sweep({**SWEEP, "grid": {"scan.size_um": [[7.0, 7.0]]}})
    with pytest.raises(SweepError, match="different sweep"):
        run_sweep(other, out, scheduler=scheduler, resume=True)
    (tmp_path / "plain").mkdir()
    with pytest.raises(SweepError, match="not a sweep folder"):
        run_sweep(other, tmp_path / "plain", scheduler=scheduler, resume=True)
    assert sorted(p.name for p in (tmp_path / "plain").iterdir()) == []


def test_a_failing_run_is_reported_the_rest_kept_and_the_sweep_never_looks_complete(tmp_path):
    (tmp_path / "corrupt.npy").write_text("not an array")             # readable, so it passes validation
    sweep = parse_sweep({"name": "fails", "base": TINY, "grid": {"sample": [
        {"kind": "microlens"}, {"kind": "heightmap", "path": str(tmp_path / "corrupt.npy"), "pixel_size_nm": 100}]}})
    out = tmp_path / "sweep"
    with pytest.raises(SweepRunError, match="1 of 2 runs failed"):
        run_sweep(sweep, out, workers=1)                          # the default local-cluster path
    good, bad = sweep.runs()
    assert (out / "runs" / f"{good.run_id}.json").exists() and not (out / "runs" / f"{bad.run_id}.json").exists()
    assert json.loads((out / "failures.json").read_text())["failed"][0]["run_id"] == bad.run_id
    assert not (out / "manifest.json").exists() and not (out / "results.csv").exists()


def test_grid_and_random_expansion_is_reproducible():
    spec = {"name": "mix", "seed": 11, "base": TINY,
            "grid": {"scan.pixels": [32, 48], "stage.creep": [True, False]},
            "random": {"draws": 5, "parameters": {"scan.line_rate_hz": {"loguniform": [0.5, 5.0]},
                                                  "seed": {"integers": [0, 3]},
                                                  "z_feedback.kp": {"uniform": [0.05, 0.2]},
                                                  "controllers": {"choice": [["none", "spi"], ["none", "diapi"]]}}}}
    first, again = parse_sweep(spec).runs(), parse_sweep(spec).runs()
    assert [(r.run_id, r.params) for r in first] == [(r.run_id, r.params) for r in again]
    assert len(first) == 2 * 2 * 5
    assert [(r.params["scan.pixels"], r.params["stage.creep"]) for r in first[::5]] == [
        (32, True), (32, False), (48, True), (48, False)]                   # grid-major, Cartesian product
    draws = [{k: r.params[k] for k in spec["random"]["parameters"]} for r in first[:5]]
    assert all(draws == [{k: r.params[k] for k in d} for r, d in zip(first[5 * i:5 * i + 5], draws)] for i in range(4))
    for r in first:
        assert 0.5 <= r.params["scan.line_rate_hz"] <= 5.0 and r.params["seed"] in range(4)
        assert r.scenario.scan.line_rate_hz == r.params["scan.line_rate_hz"] and r.scenario.seed == r.params["seed"]
        assert r.params["controllers"] in (["none", "spi"], ["none", "diapi"]) and r.scenario.scan.lines == 32
    reseeded = parse_sweep({**spec, "seed": 12}).runs()
    assert [r.params["scan.line_rate_hz"] for r in reseeded] != [r.params["scan.line_rate_hz"] for r in first]
    fewer = parse_sweep({**spec, "grid": {}, "random": {**spec["random"], "draws": 3}}).runs()
    assert [r.params for r in fewer] == [{k: v for k, v in r.params.items() if k in spec["random"]["parameters"]}
                                         for r in first[:3]]                 # more draws extend, never reshuffle


def test_run_ids_hash_the_validated_values_and_duplicates_run_once():
    ints = parse_sweep({"base": TINY, "grid": {"scan.line_rate_hz": [1, 2]}}).runs()
    floats = parse_sweep({"base": TINY, "grid": {"scan.line_rate_hz": [1.0, 2.0]}}).runs()
    assert [r.run_id for r in ints] == [r.run_id for r in floats] and ints[0].params == {"scan.line_rate_hz": 1.0}
    chosen = parse_sweep({"base": TINY, "random": {"draws": 20, "parameters": {"stage.drift": {"choice": [True, False]}}}})
    assert sorted(r.params["stage.drift"] for r in chosen.runs()) == [False, True]


def test_base_path_is_relative_to_the_sweep_file_and_indices_reach_into_lists(tmp_path):
    (tmp_path / "scenarios").mkdir()
    (tmp_path / "scenarios" / "base.yaml").write_text(json.dumps(TINY))
    (tmp_path / "scenarios" / "sweep.yaml").write_text(json.dumps(
        {"base": "base.yaml", "grid": {"scan.offset_um.1": [3.0, 4.0], "controllers.0": ["ideal"]}}))
    runs = load_sweep(tmp_path / "scenarios" / "sweep.yaml").runs()
    assert [r.scenario.scan.offset_um for r in runs] == [(2.0, 3.0), (2.0, 4.0)]
    assert runs[0].scenario.controllers == ["ideal", "spi", "diapi"]


def test_run_count_is_capped_before_expansion():
    with pytest.raises(SweepError, match=f"more than the limit of {MAX_RUNS:,}"):
        parse_sweep({"base": TINY, "grid": {"scan.pixels": list(range(16, 1016)), "scan.lines": list(range(2, 1002))}})


def test_cli_sweep_runs_and_guards_its_folder(scheduler, tmp_path):
    path = tmp_path / "one.yaml"
    path.write_text(json.dumps({"name": "one", "base": TINY, "grid": {"scan.size_um": [[8.0, 8.0]]}}))
    out = tmp_path / "out"
    result = runner.invoke(app, ["sweep", str(path), "--out", str(out), "--scheduler", scheduler])
    assert result.exit_code == 0, result.output
    assert "wrote" in result.stdout and "spi.nsl2_mean" in result.stdout and (out / "manifest.json").exists()
    for args, message in ((["--out", str(out)], "already exists"), (["--resume"], "--resume needs --out"),
                          (["--out", str(tmp_path / "x"), "--scheduler", scheduler, "--workers", "2"], "--workers")):
        result = runner.invoke(app, ["sweep", str(path), *args])
        assert result.exit_code == 2 and message in result.stderr and len(result.stderr.splitlines()) == 1
    result = runner.invoke(app, ["sweep", str(path), "--out", str(out), "--resume", "--scheduler", scheduler])
    assert result.exit_code == 0 and json.loads((out / "manifest.json").read_text())["computed_now"] == []
    assert not (tmp_path / "x").exists()


def test_a_run_gives_the_same_bits_whatever_the_blas_thread_count():
    """OpenBLAS's thread split changes rounding (at 128 x 128 the registration's least squares is
    big enough to be split); run_scenario pins one thread, so serial runs equal Dask workers'."""
    from threadpoolctl import threadpool_limits

    scenario = parse_scenario({**TINY, "scan": {**TINY["scan"], "pixels": 128, "lines": 128}, "seed": 22653219,
                               "controllers": ["none"]})
    with threadpool_limits(limits=2, user_api="blas"):
        two = run_scenario(scenario).metrics()
    with threadpool_limits(limits=1, user_api="blas"):
        one = run_scenario(scenario).metrics()
    assert two == one
