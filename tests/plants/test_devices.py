"""A batch split over the devices (`manus.plants.devices.split`): the same numbers as unsplit."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.plants.devices import BATCH, split


def _scaled(whole, parts):
    gain, (x, y) = whole, parts
    return jnp.sin(gain * x) + y, jnp.cumsum(x, axis=1) * gain


@pytest.mark.parametrize("batch", [6, 5])  # divides the two devices, and does not (run unsplit)
def test_a_split_batch_gives_the_unsplit_numbers(batch):
    x = np.linspace(0.0, 2.0, batch * 3).reshape(batch, 3)
    y = np.arange(batch * 3.0).reshape(batch, 3)
    spec = jax.sharding.PartitionSpec(BATCH)
    got = split(_scaled, jnp.asarray(1.5), (x, y), (spec, spec))
    want = _scaled(1.5, (x, y))
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    if batch % len(jax.devices()) == 0 and len(jax.devices()) > 1:
        assert got[0].sharding.num_devices == len(jax.devices())
