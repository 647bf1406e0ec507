"""References by name: the thesis's trajectories on its arm only, holding, a multi-sine; and the
recorded and reaching references' exact derivatives."""

import jax.numpy as jnp
import numpy as np
import pytest

from manus.plants.errors import ManusError
from manus.plants.references import Benign, Hold, MultiSine, Reaching, Sampled, reference_named


def test_a_reference_by_name():
    centre = np.array([0.1, 0.2])
    assert isinstance(reference_named("benign", centre), Benign)
    np.testing.assert_array_equal(reference_named("hold", centre)(1.0).q, centre)
    a, b = reference_named("multisine", centre, amplitude=0.1, seed=3), MultiSine(centre, 0.1, seed=3)
    np.testing.assert_array_equal(a(0.7).q, b(0.7).q)
    with pytest.raises(ManusError, match="the complex trajectory is the thesis's for the manus2 arm"):
        reference_named("complex", np.zeros(1), arm=False)
    with pytest.raises(ManusError, match="unknown reference 'circle'"):
        reference_named("circle", centre)
    assert isinstance(reference_named("hold", np.zeros(1), arm=False), Hold)


def test_reaching_and_sampled_references():
    move = Reaching(jnp.zeros(1), jnp.array([1.0]), jnp.array([2.0]), jnp.array([[0.5]]))
    assert float(move(0.5).q[0]) == 0.0 and float(move(3.5).q[0]) == pytest.approx(0.5)
    mid = move(2.0)  # half-way through the quintic move: half the distance at its peak speed 15/8 Δ/T
    assert float(mid.q[0]) == pytest.approx(0.25) and float(mid.qd[0]) == pytest.approx(15 / 8 * 0.5 / 2.0)
    recorded = Sampled(jnp.array([0.0, 1.0, 2.0]), jnp.array([[0.0], [2.0], [2.0]]))
    assert float(recorded(0.25).q[0]) == pytest.approx(0.5) and float(recorded(0.25).qd[0]) == pytest.approx(2.0)
