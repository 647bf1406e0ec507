"""Tests use float64 and compare against independent references (docs/architecture.md)."""

import os
import pathlib

# numpy's small batched solves (diagnose's folds) on one BLAS thread: on a busy 2-core machine
# OpenBLAS's threads spin-wait far longer than the work takes. Must precede the first numpy import.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax
import pytest

jax.config.update("jax_enable_x64", True)

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
