"""A batch split over the devices: one per CPU core (`manus.config` exposes them), each running its
share of the batch alone (`shard_map` with no collectives), as the convergence trials, the
closed-loop batches and IV's simulated windows do."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import numpy as np

BATCH = "batch"  # the mesh axis the batch is split along (out_specs name it)


def split(fn: Callable, whole, parts, out_specs):
    """`fn(whole, parts)`, with the arrays of the pytree `parts` split along their first axis (the
    batch) over the devices and those of `whole` given whole to each; `out_specs`: where the batch
    axis is in each output (`PartitionSpec`s naming `BATCH`). `fn` itself, unsplit, where there is
    one device or the batch does not divide among them. Each element of the batch is computed
    alone, so the split changes no number."""
    devices = jax.devices()
    leaves = [x for x in jax.tree.leaves(parts) if eqx.is_array(x)]
    if len(devices) < 2 or not leaves or leaves[0].shape[0] % len(devices):
        return fn(whole, parts)
    P = jax.sharding.PartitionSpec
    (whole_arrays, part_arrays), rest = eqx.partition((whole, parts), eqx.is_array)
    local = jax.shard_map(
        lambda w, p: fn(*eqx.combine((w, p), rest)),
        mesh=jax.sharding.Mesh(np.array(devices), (BATCH,)),
        in_specs=(P(), P(BATCH)),
        out_specs=out_specs,
        check_vma=False,
    )
    return local(whole_arrays, part_arrays)
