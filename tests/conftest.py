"""Tests use float64 and compare against independent references (docs/architecture.md)."""

import os
import pathlib

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
