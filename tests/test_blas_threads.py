"""The suite's own set-up: every BLAS library a test process has loaded runs one thread."""

from threadpoolctl import threadpool_info


def test_every_loaded_blas_library_runs_one_thread():
    """numpy and scipy each load an OpenBLAS; tests/conftest.py limits both (xdist already runs one
    worker per core, and a second BLAS thread per worker made the fitting tests up to 4x slower)."""
    import scipy.optimize  # noqa: F401  (what the fitting code imports)

    blas = [info for info in threadpool_info() if info["user_api"] == "blas"]
    assert len(blas) >= 1
    assert {info["filepath"]: info["num_threads"] for info in blas} == {info["filepath"]: 1 for info in blas}
