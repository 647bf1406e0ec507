"""Simulated recordings of the MANUS-2 arm with hidden effects, shared by the fit and diagnosis tests.

The arm runs under the thesis's impedance control (K = 30 N·m/rad, B = 1 N·m·s/rad, filtered
first-difference velocity) tracking a multi-sine (0.2–3 Hz, 0.3 rad per joint about the workspace
centre), with the full sensor chain (12-bit D/A, 131072-count encoder). One truth model holds every
effect with linear parameters; an effect is hidden by giving it its default (thesis or
illustrative) parameters, and left out by zeroing them, so a single compiled simulation serves
every case. Only the `delay` (a static property of the simulator) needs a second compilation.

Recordings are made once per test session (`recording` is cached).
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from manus.adaptive import diagnose
from manus.adaptive.impedance import Impedance
from manus.plants import Model, Simulator
from manus.plants.closed_loop import simulate
from manus.plants.effects import Effect
from manus.plants.recording import from_trajectory
from manus.plants.references import MultiSine
from manus.plants.structures import Manus2

SECONDS = 20.0  # also the `manus bench diagnose` size: 20 s, 2 joints, 1 kHz
AMPLITUDE = 0.3  # rad: a swing wide enough that a tilted plane's cos/sin is not a constant
NOMINAL = ("rigid", "viscous", "coulomb")  # the thesis's model (§3.5)
ALL_LINEAR = "rigid,viscous,coulomb,stribeck,asymmetry,offset,gravity,spring,cogging"
STRUCTURE = Manus2()


def truth_params(hidden: tuple[str, ...]) -> dict[str, float]:
    """The truth: the nominal effects at the thesis's values, the hidden ones at their defaults,
    every other effect zero."""
    model = Model(STRUCTURE, ALL_LINEAR)
    nominal = Model(STRUCTURE, ",".join(NOMINAL)).defaults()
    extra: dict[str, float] = {}
    for h in hidden:
        if h not in NOMINAL and h != "delay":
            extra.update(Model(STRUCTURE, h).defaults())
    return {k: nominal.get(k, extra.get(k, 0.0)) for k in model.defaults()}


def effect(model: Model, name: str) -> Effect:
    """The effect `name` of `model`, which the test knows the model holds."""
    found = model.get(name)
    assert found is not None, f"the model holds no {name}"
    return found


def nominal_without(hidden: tuple[str, ...]) -> str:
    """The model the analysis starts from: the nominal one, less any hidden nominal effect."""
    return ",".join(e for e in NOMINAL if e not in hidden)


@functools.cache
def recording(hidden: tuple[str, ...] = (), seconds: float = SECONDS, seed: int = 0):
    """A closed-loop recording whose truth holds the nominal effects plus `hidden`."""
    spec = ALL_LINEAR + (",delay:1ms" if "delay" in hidden else "")
    plant = Simulator(Model(STRUCTURE, spec), truth_params(hidden))
    assert plant.actuator is not None
    reference = MultiSine((0.464, 2.409), AMPLITUDE, seed=seed)
    controller = Impedance(30.0, 1.0, n_joints=2, limit=plant.actuator.limit)
    traj = simulate(plant, controller, reference, seconds, key=jax.random.PRNGKey(seed))
    rec = from_trajectory(traj, plant.rate_hz, "manus2", 131072, {"truth": "+".join(hidden) or "nominal"})
    rec.path = f"<simulated, hidden: {'+'.join(hidden) or 'nothing'}>"
    return rec


def discover(rec, model: str, max_steps: int = 6):
    """Diagnose, add the verdict (as found: its spec), repeat until the verdict is null. Returns
    the diagnoses, the last with a null verdict unless the cap was reached."""
    from manus.adaptive import Columns, prepare

    data = prepare(rec)
    cols = Columns(data)
    out = []
    for _ in range(max_steps + 1):
        d = diagnose(data, model, columns=cols)
        out.append(d)
        if d.verdict is None or d.verdict.effect == "compliance":
            break
        model = f"{d.base.model.spec},{d.verdict.spec}"
    return out


def square_wave_recording(seconds: float = 6.0):
    """Thesis Figs. 4-12 and 4-20: the arm with a compliant shaft (the 218.7 Hz mode), driven open
    loop by square waves (10 Hz, 4 N·m on joint 1; 7 Hz, 2 N·m on joint 2): the steps ring the mode."""
    import equinox as eqx
    import jax.numpy as jnp

    from manus.plants.recording import Recording

    sim = Simulator(Model(STRUCTURE, "rigid,viscous,coulomb,compliance"))
    t = np.arange(int(seconds * sim.rate_hz)) * sim.dt
    taus = np.stack(
        [4.0 * np.sign(np.sin(2 * np.pi * 10 * t + 1e-9)), 2.0 * np.sign(np.sin(2 * np.pi * 7 * t + 0.5))], 1
    )
    state, _ = sim.reset()
    run = eqx.filter_jit(lambda s0, u: jax.lax.scan(lambda s, x: (sim.step(s, x)[0], (sim.measure(s), s.qd)), s0, u))
    _, (q, qd) = run(state, jnp.asarray(taus))
    meta = {"sample_rate_hz": "1000", "structure": "manus2", "command_hold": "zoh", "counts_per_rev": "131072"}
    return Recording(t, np.asarray(q), taus, np.asarray(qd), meta, {}, "<simulated square wave, compliant shaft>")


def emps(name: str = "DATA_EMPS.mat"):
    """A file of the EMPS benchmark (read once), or skip when ../shared is not beside the clone."""
    import pytest

    from tests.conftest import EMPS

    if not (EMPS / name).exists():
        pytest.skip("../shared/data/emps is not beside the clone")
    return _read(str(EMPS / name))


@functools.cache
def _read(path: str):
    from manus.plants.recording import read

    return read(path)
