"""Sweeps: the same grid locally (one vmapped call) and on a local Dask cluster (chunks per
worker, each vmapped) give the same result; trials do not depend on the batch they sit in."""

import numpy as np
import pytest

from manus.experiments.stability import sweep
from manus.experiments.stability.search import read_map
from manus.experiments.stability.steptest import StepTest, verdict
from manus.plants.errors import ManusError

TEST = StepTest(seconds=2.5, at=1.0)  # a shorter step test: the same code, cheaper
B_CS = np.array([0.0, 12.0, 24.0, 36.0])
KS = np.array([400.0, 1500.0, 3000.0, 6000.0, 9000.0])


@pytest.fixture(scope="module")
def local_grid():
    return sweep.grid(TEST, B_CS, KS)


def test_distributed_sweep_equals_the_local_one(local_grid):
    from distributed import LocalCluster

    # distributed's annotations: dashboard_address=None (no dashboard) is documented but typed str, and the
    # context manager's type covers the asynchronous cluster too
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:  # pyright: ignore[reportArgumentType]
        remote = sweep.grid(TEST, B_CS, KS, cluster=cluster.scheduler_address, chunk=8, progress=True)  # pyright: ignore[reportAttributeAccessIssue]
    for name, a, b in zip(local_grid._fields, local_grid, remote, strict=True):
        assert a.shape == (len(B_CS), len(KS)), name
        if name == "psd":  # the FFT's rounding may depend on its batch: equal to 1e-12
            np.testing.assert_allclose(a, b, rtol=1e-10, atol=0)
        else:  # the trajectories themselves are bit-identical
            np.testing.assert_array_equal(a, b, err_msg=name)
    np.testing.assert_array_equal(verdict(local_grid, TEST), verdict(remote, TEST))
    assert len(set(verdict(local_grid, TEST).ravel())) == 3  # the grid sees stable, Type 1 and Type 2


def test_a_trial_does_not_depend_on_its_batch(local_grid):
    one = sweep.run(TEST, [KS[2]], [B_CS[1]])  # alone, padded with copies of itself
    assert one.amplitude[0] == local_grid.amplitude[1, 2]
    smap = read_map(TEST, B_CS, KS, local_grid)
    assert smap.limit.shape == (len(B_CS),)


def test_bucket_sizes_share_compilations():
    assert [sweep.bucket(n) for n in (1, 100, 128, 129, 3000, 5000)] == [128, 128, 128, 256, 4096, 5120]
    assert sweep.bucket(129, devices=3) == 258


def test_unreachable_scheduler_is_a_clear_error():
    with pytest.raises(ManusError, match="--cluster"):
        sweep.client_for("tcp://127.0.0.1:9", timeout="1s")
