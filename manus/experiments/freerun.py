"""Free-run simulation of a fitted model against a recording (the position half of `compare`).

The fitted model (`manus.adaptive.Fit`: its effects with their non-linear parameters, and θ) is
simulated with the JAX simulator (`manus.plants.simulator.Simulator`: the same effects, set-valued
friction), driven the way the rig was:

- **closed loop on the recorded reference, over the whole recording,** when the recording says
  which controller ran and logged its reference: manus's impedance controller (metadata
  `controller: impedance K=.. B=..`, columns `qref1..n`, as `manus simulate` writes), or the EMPS
  rig's P-PD loop vir = kp·kv·(qg − qm) − kv·v̂, force = gtau·vir (metadata `kp`, `kv`, `gtau`,
  column `qg`; replayed on the recorded qm it gives the recorded `vir` within 0.7 %). The
  simulated arm then meets the same reference through the same controller, as the real one did,
  on the recorded encoder grid;
- **open loop on the recorded torque, in windows** otherwise: the recording is cut into windows of
  `manus.adaptive.identify.instruments.WINDOW_S`, each simulated from the measured (filtered) state
  at its start, all at once (the simulation IDIM-IV's instruments come from, compiled once for
  both). Over a whole recording a model with friction driven by open-loop torque drifts (a small
  error in the Coulomb level or the inertia integrates into a position error that nothing pulls
  back), so its position fit would say more about the drift than about the model; a window says
  how far the model's own motion strays from the arm's in that time. The figure says so.

Each control period is cut into sub-steps of at most `instruments.SUBSTEP_S` (the simulator is
second order; at 1 kHz two sub-steps, at 5 kHz one), of `instruments.FINE_SUBSTEP_S` where those
diverge.

Under stiff closed-loop control the position follows the reference whatever the model, so the
position fit alone is flattering: the tracking error q − q_ref, which the plant's dynamics shape,
is compared too.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from manus.adaptive.controllers import PPD
from manus.plants.errors import ManusError
from manus.plants.references import Sampled


def nrmse_fit(y: np.ndarray, yhat: np.ndarray) -> np.ndarray:
    """Per column, 100 (1 − ‖y − ŷ‖ / ‖y − mean y‖) [%] (MATLAB `compare`'s fit)."""
    y, yhat = np.asarray(y, float).reshape(len(y), -1), np.asarray(yhat, float).reshape(len(y), -1)
    den = np.linalg.norm(y - y.mean(0), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, 100 * (1 - np.linalg.norm(y - yhat, axis=0) / den), np.nan)


@dataclass
class FreeRun:
    t: np.ndarray
    q: np.ndarray  # measured (T, n)
    q_sim: np.ndarray  # simulated (T, n)
    mode: str  # "closed loop" | "open loop"
    how: str  # one line: what drove the simulation
    fit_q: np.ndarray  # NRMSE fit of the positions per joint [%]
    q_ref: np.ndarray | None = None  # the recorded reference (closed loop)
    fit_tracking: np.ndarray | None = None  # NRMSE fit of the tracking error q − q_ref [%]

    def report(self) -> dict:
        out = {"mode": self.mode, "how": self.how, "position_fit_percent": self.fit_q.tolist()}
        if self.fit_tracking is not None:
            out["tracking_error_fit_percent"] = self.fit_tracking.tolist()
        return out


def _reference(rec) -> np.ndarray | None:
    n = rec.n_joints
    if all(f"qref{i + 1}" in rec.extra for i in range(n)):
        return np.stack([rec.extra[f"qref{i + 1}"] for i in range(n)], 1)
    if n == 1 and "qg" in rec.extra:
        return rec.extra["qg"][:, None]
    return None


def _controller(rec, n: int, limit: float | None):
    """The controller the recording says ran, with a one-line description, or None. `limit`: the
    actuator's torque limit, which an impedance controller clips its command to (None: its own)."""
    from manus.adaptive.impedance import Impedance

    meta = rec.meta
    m = re.match(r"\s*impedance\s+K=([0-9.eE+-]+)\s+B=([0-9.eE+-]+)", meta.get("controller", ""))
    if m:
        k, b = float(m.group(1)), float(m.group(2))
        controller = Impedance(k, b, n_joints=n) if limit is None else Impedance(k, b, n_joints=n, limit=limit)
        return controller, f"impedance K={k:g} B={b:g} (filtered first difference)"
    if all(k in meta for k in ("kp", "kv", "gtau")) and "qg" in rec.extra:
        kp, kv, gtau = (float(meta[k]) for k in ("kp", "kv", "gtau"))
        return PPD(kp, kv, gtau, rec.dt), f"the EMPS P-PD loop kp={kp:g} kv={kv:g} gtau={gtau:.4g}"
    return None


def free_run(f, open_loop: bool = False) -> FreeRun:
    """Simulate the fitted model `f` (a `manus.adaptive.Fit`) against its recording: a serial
    chain's with physically consistent parameters (`manus.adaptive.identify.consistency.physical`:
    the fit's own where it has been through that stage, as `fit` returns it)."""
    from manus.adaptive.identify.consistency import physical
    from manus.adaptive.identify.instruments import FINE_SUBSTEP_S, WINDOW_S, substeps, windows
    from manus.plants.closed_loop import simulate
    from manus.plants.errors import ModelError
    from manus.plants.simulator import Actuator, Encoder, Simulator

    rec = f.data.rec
    model = f.model
    if not model.has("rigid"):
        raise ModelError("a free run needs the 'rigid' effect (the model's inertia); fit with rigid to simulate")
    n = rec.n_joints
    if f.consistency is None:  # not through the consistent stage yet (a chain's estimate breaking physics moves)
        f = physical(f)
    params = {k: float(v) for k, v in f.params.items()}
    actuator = Actuator() if rec.structure_name == "manus2" else None
    ref = _reference(rec)
    ctl = None if open_loop or ref is None else _controller(rec, n, None if actuator is None else actuator.limit)
    if ctl is None:
        run = windows(f.data, model, params)
        if run is None:
            raise ModelError("the fitted model cannot be simulated from the recorded command (it diverges)")
        q_sim, mode = run[0], "open loop"
        how = (
            f"open loop: the recorded torque played back in windows of {WINDOW_S:g} s, each from the measured "
            "state (over a whole recording friction models drift: no loop pulls them back)"
        )
    else:
        controller, how = ctl
        reference = Sampled(jnp.asarray(rec.t - rec.t[0]), jnp.asarray(ref))
        mode, how = "closed loop", f"closed loop: {how} on the recorded reference"
        encoder = Encoder(step=f.data.step) if f.data.step > 0 else None
        steps = dict.fromkeys((substeps(rec.dt), substeps(rec.dt, FINE_SUBSTEP_S)))
        for i, step in enumerate(steps):  # finer where the period's sub-steps diverge (as IV's windows)
            plant = Simulator(
                model,
                params,
                rate_hz=rec.sample_rate_hz,
                substeps=step,
                actuator=actuator,
                encoder=encoder,
                q0=rec.q[0],
            )
            try:
                q_sim = np.asarray(simulate(plant, controller, reference, len(rec) / rec.sample_rate_hz).q)[: len(rec)]
                break
            except ModelError:
                if i == len(steps) - 1:
                    raise
    q = rec.q[: len(q_sim)]
    if f.unconstrained is not None:
        how += "; the physically consistent parameters (the estimate breaks physics)"
    out = FreeRun(rec.t[: len(q_sim)], q, q_sim, mode, how, nrmse_fit(q, q_sim))
    if mode == "closed loop":
        assert ref is not None  # the closed loop follows the recorded reference
        out.q_ref = ref[: len(q_sim)]
        out.fit_tracking = nrmse_fit(q - out.q_ref, q_sim - out.q_ref)
    return out


def free_run_or_reason(f, open_loop: bool = False) -> FreeRun | str:
    """The free run, or a one-line reason why there is none."""
    try:
        return free_run(f, open_loop=open_loop)
    except ManusError as e:
        return str(e)
