"""Fixtures the command tests share."""

import argparse

import pytest

from tests.estimators.conftest import arm_recording  # noqa: F401  (the simulated arm's recording)


@pytest.fixture
def calibrate_args():
    """The options of `manus bench diagnose --calibrate` at their defaults, with the values given."""
    from manus.runs.bench import diagnose as bench

    def make(**values) -> argparse.Namespace:
        p = argparse.ArgumentParser()
        bench.add_arguments(p)
        return argparse.Namespace(**{**vars(p.parse_args(["--calibrate"])), **values})

    return make


@pytest.fixture(scope="module")
def files():
    """The DFKI double pendulum's recordings (../shared/data/real/dfki_double_pendulum), or a skip."""
    from tests.conftest import SHARED

    found = sorted((SHARED / "data" / "real" / "dfki_double_pendulum").glob("A0_trajectory_0*.csv"))
    if not found:
        pytest.skip("../shared/data/real/dfki_double_pendulum is not beside the clone")
    return found
