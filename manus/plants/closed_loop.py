"""Closed-loop simulation: any plant, any controller stepper, any reference, in one `lax.scan`.

Each tick k (period T): the controller reads the measured position q_k and the reference at
t_k = kT and computes the command u_k; the plant holds u_k over [t_k, t_k + T) (after its own
delay) and returns q_{k+1}. This is the thesis's sampling order: read, compute, write (§3.1).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.sharding import PartitionSpec

from manus.plants.devices import BATCH, split
from manus.plants.errors import ModelError
from manus.plants.stepper import Controller, Plant, Reference


class Trajectory(NamedTuple):
    """What a closed-loop run produced, one row per tick: arrays (T,) or (T, n), JAX's inside the
    scan and numpy's once returned (the same structure also carries their sharding specs)."""

    t: Any
    q: Any  # measured (quantized) positions
    tau: Any  # commanded torques
    q_true: Any  # true positions of the measured coordinate
    qd_true: Any  # true velocities
    q_ref: Any  # reference positions


def _tick(plant: Plant, controller: Controller, reference: Reference):
    def tick(carry, k):
        pstate, cstate, q = carry
        t = k * plant.dt
        ref = reference(t)
        cstate, u = controller.step(cstate, q, ref)
        q_true, qd_true = plant.truth(pstate)
        pstate, q_next = plant.step(pstate, u)
        return (pstate, cstate, q_next), Trajectory(t, q, u, q_true, qd_true, ref.q)

    return tick


def start(plant: Plant, controller: Controller, reference: Reference, key=None):
    """The carry of a run before its first tick: the plant at the reference's start, at rest."""
    pstate, q = plant.reset(key, q0=reference(0.0).q)
    return pstate, controller.init(q), q


def rollout(plant: Plant, controller: Controller, reference: Reference, steps: int, key=None) -> Trajectory:
    """`steps` ticks in one `lax.scan`; pure (jit, vmap and grad go through)."""
    carry = start(plant, controller, reference, key)
    _, traj = jax.lax.scan(_tick(plant, controller, reference), carry, jnp.arange(steps))
    return traj


@eqx.filter_jit
def _chunk(plant, controller, reference, carry, ks):
    return jax.lax.scan(_tick(plant, controller, reference), carry, ks)


def simulate(
    plant: Plant,
    controller: Controller,
    reference: Reference,
    seconds: float,
    key=None,
    progress: bool | Callable[[float], None] = False,
    chunk_seconds: float = 1.0,
) -> Trajectory:
    """Run the closed loop for `seconds`; returns numpy arrays.

    With `progress=True` a progress bar goes to stderr (the run is then scanned in chunks of
    `chunk_seconds`, compiled once); a callable receives the fraction done instead.
    """
    steps = int(round(seconds / plant.dt))
    if not progress:
        traj = eqx.filter_jit(rollout)(plant, controller, reference, steps, key)
        return _finite(Trajectory(*map(np.asarray, traj)), plant.dt)
    chunk = max(1, int(round(chunk_seconds / plant.dt)))
    carry = eqx.filter_jit(start)(plant, controller, reference, key)
    parts = []
    bar = None
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=steps, unit="tick", file=sys.stderr, desc="simulate", leave=False)
    for k0 in range(0, steps, chunk):
        ks = jnp.arange(k0, min(k0 + chunk, steps))
        if len(ks) < chunk:  # the last, shorter chunk: pad and trim (one compilation)
            ks = jnp.arange(k0, k0 + chunk)
        carry, traj = _chunk(plant, controller, reference, carry, ks)
        parts.append(jax.tree.map(np.asarray, traj))
        done = min(k0 + chunk, steps)
        if bar is not None:
            bar.update(done - k0)
        elif callable(progress):
            progress(done / steps)
    if bar is not None:
        bar.close()
    return _finite(Trajectory(*(np.concatenate(x)[:steps] for x in zip(*parts, strict=True))), plant.dt)


def _finite(traj: Trajectory, dt: float) -> Trajectory:
    """The run, or a `ModelError` where the loop diverged (an unstable discrete loop: gains too
    stiff for the sample rate or for a light plant), instead of a recording of NaN."""
    rows = len(traj.t)
    bad = ~np.isfinite(np.c_[traj.q_true.reshape(rows, -1), traj.tau.reshape(rows, -1)]).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        peak = float(np.nanmax(np.abs(traj.tau[:k]))) if k else float("nan")
        raise ModelError(
            f"the closed loop diverged: positions or torques are not finite from t = {k * dt:.4g} s "
            f"(tick {k}; the largest torque before, {peak:.3g}): the loop is unstable at {1 / dt:g} Hz, "
            "its gains too stiff for the sample rate or the plant too light for them (lower the "
            "stiffness and damping, raise the rate or the physics sub-steps, or limit the torque)"
        )
    return traj


def simulate_batch(
    plant: Plant,
    controller: Controller,
    reference: Reference,
    seconds: float,
    keys: Array,
    batched: tuple[str, ...] = (),
    every: int = 1,
) -> Trajectory:
    """Many trials at once: one per key in `keys` (B, 2). `batched` names which of "plant",
    "controller", "reference" carry a leading batch axis on their array leaves (e.g.
    different gains or initial estimates per trial); the others are shared. Returns numpy
    arrays (B, T) or (B, T, n), recording every `every`-th tick (ticks 0, every, 2·every, ...;
    the full 1 kHz record of 1000 trials × 5 s is 440 MB).

    The trials are vmapped inside the time scan (every per-trial scalar becomes a batch
    vector) and, when B divides the number of devices, split over the devices (`shard_map`;
    `--xla_force_host_platform_device_count` makes each CPU core one, see `manus.runs.cli`).
    """
    steps = int(round(seconds / plant.dt))
    unknown = set(batched) - {"plant", "controller", "reference"}
    if unknown:
        raise ValueError(f"batched: unknown part(s) {sorted(unknown)}")
    if int(every) != every or every < 1:
        raise ValueError(f"every: a positive whole number of ticks, not {every!r}")
    traj = _batch(plant, controller, reference, keys, steps, tuple(sorted(batched)), int(every))
    return Trajectory(*(np.moveaxis(np.asarray(x), -1, 0) for x in traj))  # views (B, T, ...)


@eqx.filter_jit
def _batch(plant, controller, reference, keys, steps: int, batched: tuple[str, ...], every: int) -> Trajectory:
    """The recorded ticks of all trials, arrays (T, ..., B): the batch axis last, so that each
    tick writes whole rows (the per-trial scalars are batch vectors)."""
    parts = ("plant", "controller", "reference")
    axes = tuple(eqx.if_array(0) if name in batched else None for name in parts)

    def run(plant, controller, reference, keys):
        tick = eqx.filter_vmap(
            lambda p, c, r, carry, k: _tick(p, c, r)(carry, k), in_axes=(*axes, 0, None), out_axes=(0, -1)
        )

        def chunk(carry, k0):  # record the first of `every` ticks
            carry, row = tick(plant, controller, reference, carry, k0)
            carry, _ = jax.lax.scan(
                lambda c, k: (tick(plant, controller, reference, c, k)[0], None), carry, k0 + jnp.arange(1, every)
            )
            return carry, row

        carry = eqx.filter_vmap(start, in_axes=(*axes, 0))(plant, controller, reference, keys)
        return jax.lax.scan(chunk, carry, jnp.arange(0, steps, every))[1]

    named = {"plant": plant, "controller": controller, "reference": reference}
    whole = {k: v for k, v in named.items() if k not in batched}
    parts = ({k: v for k, v in named.items() if k in batched}, keys)

    def on(whole, parts):  # (every device runs its own trials)
        given = {**whole, **parts[0]}
        return run(given["plant"], given["controller"], given["reference"], parts[1])

    return split(on, whole, parts, Trajectory(PartitionSpec(None, BATCH), *[PartitionSpec(None, None, BATCH)] * 5))
