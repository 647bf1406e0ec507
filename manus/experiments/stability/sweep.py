"""Sweeps at scale: thousands of step tests over a (k, b_c) grid, vmapped, locally or on Dask.

Locally the whole set of points is one vmapped, jitted call (`manus.experiments.stability.steptest.batched`),
its batch split across the host's devices when there are several (`--xla_force_host_platform_
device_count`, set by the `manus` command: one per core). With `cluster` (a Dask scheduler
address such as ``tcp://10.0.0.5:8786``, or a `distributed.Client`) the points are cut into
equal chunks (the last one padded, so each worker compiles once), each chunk runs vmapped on a
worker, and a progress bar on stderr counts the chunks as they come back. Results come back in
the order of the points, identical to the local ones (every trial is computed the same way
whatever the batch it sits in).
"""

from __future__ import annotations

import sys

import numpy as np

from manus.experiments.stability.steptest import Metrics, StepTest, batched
from manus.plants.errors import ManusError, require

CHUNK = 512  # points per Dask task


def local(test: StepTest, k, b_c, bucketed: bool = True) -> Metrics:
    """Metrics of the trials (k_i, b_c_i) (arrays of one shape), in one vmapped call (its batch
    padded to a `bucket` size unless `bucketed` is False)."""
    import jax
    import jax.numpy as jnp

    k, b_c = np.broadcast_arrays(np.asarray(k, float), np.asarray(b_c, float))
    shape, n = k.shape, k.size
    devices = jax.devices()
    pad = (bucket(n, len(devices)) if bucketed else -(-n // len(devices)) * len(devices)) - n
    flat = [np.concatenate([x.ravel(), np.repeat(x.ravel()[-1:], pad)]) for x in (k, b_c)]
    if len(devices) > 1:
        from jax.sharding import Mesh, NamedSharding, PartitionSpec

        sharding = NamedSharding(Mesh(np.array(devices), ("points",)), PartitionSpec("points"))
        flat = [jax.device_put(x, sharding) for x in flat]
    else:
        flat = [jnp.asarray(x) for x in flat]
    out = batched(test)(*flat)
    return Metrics(*(np.asarray(x)[:n].reshape(shape) for x in out))


def bucket(n: int, devices: int = 1) -> int:
    """The batch size n is padded to: 128, a power of two up to 4096, then a multiple of 1024,
    and a multiple of the device count, so that the small batches of a search share one
    compilation (a compilation costs more than a hundred trials)."""
    size = max(128, 1 << (n - 1).bit_length()) if n <= 4096 else -(-n // 1024) * 1024
    return -(-size // devices) * devices


def _chunk(test: StepTest, k: np.ndarray, b_c: np.ndarray) -> Metrics:
    """One Dask task: a chunk of points, vmapped, on whichever worker runs it."""
    import jax

    jax.config.update("jax_enable_x64", True)  # the worker may not have been started by `manus`
    return local(test, k, b_c, bucketed=False)  # chunks are of equal size already


def client_for(cluster, timeout: str = "10s"):
    """A `distributed.Client` for an address, or the client given."""
    Client = require("distributed", "cluster").Client

    if isinstance(cluster, Client):
        return cluster
    try:
        return Client(cluster, timeout=timeout)
    except (OSError, TimeoutError, ValueError) as e:
        raise ManusError(f"--cluster {cluster}: cannot reach the Dask scheduler ({e})") from None


def distributed(test: StepTest, k, b_c, cluster, chunk: int = CHUNK, progress: bool = True) -> Metrics:
    """The same as `local`, on a Dask cluster: equal chunks of `chunk` points per task."""
    k, b_c = np.broadcast_arrays(np.asarray(k, float), np.asarray(b_c, float))
    shape, n = k.shape, k.size
    pad = -n % chunk
    k, b_c = (np.concatenate([x.ravel(), np.repeat(x.ravel()[-1:], pad)]) for x in (k, b_c))
    parts = [(k[i : i + chunk], b_c[i : i + chunk]) for i in range(0, n + pad, chunk)]
    client = client_for(cluster)
    try:
        results = _gather(
            client, [client.submit(_chunk, test, a, b, pure=False) for a, b in parts], f"sweep {n} points", progress
        )
    finally:
        if client is not cluster:  # ours: made from an address
            client.close()
    return Metrics(*(np.concatenate(x)[:n].reshape(shape) for x in zip(*results, strict=True)))


def _gather(client, futures, desc: str, progress: bool) -> list:
    """The futures' results in their order, a progress bar on stderr as they complete."""
    from distributed import as_completed
    from tqdm import tqdm

    index = {f.key: i for i, f in enumerate(futures)}
    results = [None] * len(futures)
    with tqdm(total=len(futures), unit="chunk", desc=desc, file=sys.stderr, disable=not progress, leave=False) as bar:
        for future in as_completed(futures):
            results[index[future.key]] = future.result()
            bar.update(1)
    return results


def run(test: StepTest, k, b_c, cluster=None, chunk: int = CHUNK, progress: bool = True) -> Metrics:
    """Metrics of every trial (k_i, b_c_i): locally in one vmapped call, or on `cluster`."""
    if cluster is None:
        return local(test, k, b_c)
    return distributed(test, k, b_c, cluster, chunk, progress)


def grid(test: StepTest, b_cs, ks, cluster=None, chunk: int = CHUNK, progress: bool = True) -> Metrics:
    """Metrics over the grid, shape (len(b_cs), len(ks)): rows b_c, columns k."""
    K, B = np.meshgrid(np.asarray(ks, float), np.asarray(b_cs, float))
    return run(test, K, B, cluster, chunk, progress)
