"""Closed-loop simulation: any plant, any controller stepper, any reference, in one `lax.scan`.

Each tick k (period T): the controller reads the measured position q_k and the reference at
t_k = kT and computes the command u_k; the plant holds u_k over [t_k, t_k + T) (after its own
delay) and returns q_{k+1}. This is the thesis's sampling order: read, compute, write (§3.1).
"""

from __future__ import annotations

import sys
from typing import Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from plants.stepper import Controller, Plant, Reference


class Trajectory(NamedTuple):
    """What a closed-loop run produced, one row per tick: arrays (T,) or (T, n)."""

    t: Array
    q: Array  # measured (quantized) positions
    tau: Array  # commanded torques
    q_true: Array  # true positions of the measured coordinate
    qd_true: Array  # true velocities
    q_ref: Array  # reference positions


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


def simulate(plant: Plant, controller: Controller, reference: Reference, seconds: float, key=None,
             progress: bool | Callable[[float], None] = False, chunk_seconds: float = 1.0) -> Trajectory:
    """Run the closed loop for `seconds`; returns numpy arrays.

    With `progress=True` a progress bar goes to stderr (the run is then scanned in chunks of
    `chunk_seconds`, compiled once); a callable receives the fraction done instead.
    """
    steps = int(round(seconds / plant.dt))
    if not progress:
        traj = eqx.filter_jit(rollout, )(plant, controller, reference, steps, key)
        return Trajectory(*map(np.asarray, traj))
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
    return Trajectory(*(np.concatenate(x)[:steps] for x in zip(*parts)))


def simulate_batch(plant: Plant, controller: Controller, reference: Reference, seconds: float, keys: Array,
                   batched: tuple[str, ...] = ()) -> Trajectory:
    """Many trials at once (vmapped): one per key in `keys` (B, 2). `batched` names which of
    "plant", "controller", "reference" carry a leading batch axis on their array leaves
    (e.g. different gains or initial estimates per trial); the others are shared."""
    steps = int(round(seconds / plant.dt))
    unknown = set(batched) - {"plant", "controller", "reference"}
    if unknown:
        raise ValueError(f"batched: unknown part(s) {sorted(unknown)}")
    axes = tuple(eqx.if_array(0) if name in batched else None for name in ("plant", "controller", "reference"))
    run = eqx.filter_vmap(lambda p, c, r, k: rollout(p, c, r, steps, k), in_axes=(*axes, 0))
    return Trajectory(*map(np.asarray, eqx.filter_jit(run)(plant, controller, reference, keys)))
