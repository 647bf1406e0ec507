"""A simulated recording: a plant under closed-loop control following a reference, recorded as a
rig would log it, with its true velocities beside the measured positions.

The controller is the thesis's impedance law (K = 30 N·m/rad, B = 1 N·m·s/rad by default), or on
a serial robot (a URDF) the computed torque of its own parameters along the reference plus a PD
on each joint, by default a 5 Hz critically damped loop on the joint's inertia at the centre."""

from __future__ import annotations

import numpy as np

from manus.experiments.sizing import rms

SERIAL_PD_HZ = 5.0  # a serial robot's default PD bandwidth around its computed torque


def controller_for(plant, serial: bool, stiffness=None, damping=None):
    """(controller, one line saying what it is) for `plant`: impedance, or on a serial robot
    computed torque + PD. `stiffness`, `damping`: the gains (None: the defaults above)."""
    import jax.numpy as jnp

    from manus.adaptive.impedance import Impedance
    from manus.plants.simulator import workspace_centre

    n = plant.model.n_joints
    if serial:  # a robot arm under gravity: the URDF's computed torque along the reference, plus a PD
        from manus.plants.serial_sim import Feedforward

        chain = plant.model.structure
        centre = np.asarray(workspace_centre(plant.model))
        h = np.diag(np.asarray(chain.mass_matrix(jnp.asarray(centre), jnp.asarray(chain.defaults))))
        w = 2 * np.pi * SERIAL_PD_HZ
        k = h * w**2 if stiffness is None else np.full(n, stiffness)
        b = 2 * h * w if damping is None else np.full(n, damping)
        how = (
            f"computed torque (the URDF's parameters) + PD K={', '.join(f'{x:.3g}' for x in k)} "
            f"B={', '.join(f'{x:.3g}' for x in b)}"
        )
        # per-joint gains: Feedforward broadcasts them (its gains are unannotated, so read as float)
        return Feedforward(chain, plant.dt, stiffness=k, damping=b), how
    k, b = (30.0 if stiffness is None else stiffness), (1.0 if damping is None else damping)
    return Impedance(k, b, n_joints=n, limit=plant.actuator.limit), f"impedance K={k:g} B={b:g}"


def simulated_recording(
    plant, controller, how: str, reference, reference_name: str, seconds: float, seed: int, counts: float
):
    """`seconds` of `plant` under `controller` (described by `how`) following `reference`
    (called `reference_name`), its noise from `seed`, as a recording with its metadata; `counts`
    per revolution of the encoder (0: none)."""
    import jax

    from manus.plants import recording
    from manus.plants.closed_loop import simulate

    traj = simulate(plant, controller, reference, seconds, key=jax.random.PRNGKey(seed), progress=seconds > 5)
    return recording.from_trajectory(
        traj,
        plant.rate_hz,
        plant.model.structure,
        counts if counts > 0 else None,
        {"truth": plant.model.spec, "reference": reference_name, "controller": how},
    )


def tracking_rms(rec) -> list[float]:
    """The RMS of q − q_ref per joint of a recording that logged its reference."""
    return rms(rec.q - np.stack([rec.extra[f"qref{i + 1}"] for i in range(rec.n_joints)], 1)).tolist()
