"""The estimator registry refuses what it does not know, in one line naming what it knows."""

import jax.numpy as jnp
import numpy as np
import pytest

from manus import estimators
from manus.plants.errors import ManusError


def test_make_refuses_what_it_does_not_know():
    with pytest.raises(ManusError, match=r"unknown estimator 'kalmann'.*first_difference.*foaw"):
        estimators.make("kalmann")
    with pytest.raises(ManusError, match=r"kalman_ca has no setting bandwidth.*takes q, steady"):
        estimators.make("kalman_ca", bandwidth=3.0)
    with pytest.raises(ManusError, match="must be positive"):
        estimators.make("levant", lipschitz=-1.0)
    with pytest.raises(ManusError, match=r"unknown parameter.*a9"):
        estimators.make("kalman_model", params={"a9": 1.0})
    with pytest.raises(ManusError, match="parameters break physics: a1 = -1"):
        estimators.make("luenberger_model", params={"a1": -1.0})
    est = estimators.make("luenberger_model", n_joints=1, structure="axis")
    with pytest.raises(ManusError, match="shape"):
        est.with_params(est.init(jnp.zeros(1)), np.ones(7))
    with pytest.raises(ManusError, match="no model"):
        estimators.make("luenberger").with_params(None, {})
    assert set(estimators.KNOBS) == set(estimators.NAMES) - {"first_difference"}
    assert len(estimators.NAMES) == len(set(estimators.NAMES)) >= 9
