"""Tests use float64 and compare against independent references (docs/architecture.md)."""

import os
import pathlib

# numpy's small batched solves (diagnose's folds) on one BLAS thread: on a busy 2-core machine
# OpenBLAS's threads spin-wait far longer than the work takes. Must precede the first numpy import.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax
import pytest

jax.config.update("jax_enable_x64", True)

# Test modules that take long (calibration sets, the independent simulator, benches, convergence
# trials, no-crash sweeps, hardware loops, real data): marked `slow`, so that `make test` runs the
# others first (`pytest -m "not slow"`) and these after (`pytest -m slow`). By file name, so a
# module keeps its mark when it moves between folders.
SLOW = {
    "test_bench_converge.py",
    "test_bench_robot.py",
    "test_bench_sim.py",
    "test_calibration.py",
    "test_chain_calibration.py",
    "test_converge.py",
    "test_convergence.py",
    "test_dfki_serial.py",
    "test_diagnose.py",
    "test_fit_cmds.py",
    "test_hardware.py",
    "test_independent.py",
    "test_no_crash.py",
    "test_no_crash_serial.py",
    "test_score_test.py",
    "test_serial_adaptation.py",
    "test_serial_cmds.py",
    "test_stability_cmd.py",
    "test_sweep.py",
    "test_sysid.py",
}


def pytest_collection_modifyitems(items):
    for item in items:
        if item.path.name in SLOW:
            item.add_marker(pytest.mark.slow)


SHARED = pathlib.Path(__file__).resolve().parents[1].parent / "shared"
EMPS = SHARED / "data" / "emps"


@pytest.fixture
def emps_dir():
    if not EMPS.exists():
        pytest.skip("../shared/data/emps is not beside the clone")
    return EMPS


@pytest.fixture(autouse=True)
def _headless_plots():
    os.environ.setdefault("MPLBACKEND", "Agg")
