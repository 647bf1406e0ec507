"""Parameter-convergence trials of the Slotine–Li adaptive controller (thesis App. C), a batch
of trials at once.

Each trial starts at rest at the centre of the workspace and follows the trajectory for a number
of seconds (the thesis's trial: 1 s to reach the centre, then 4 s of trajectory; here the arm
starts there). The trials differ in their initial estimates (each parameter uniform within
±`init_spread` of its nominal value), their gains (Γ, Λ and K_D each scaled by a log-uniform
factor within ×/÷ (1 + `gain_spread`)) and their noise seed (the plant's torque noise). All run
in one vmapped `lax.scan` (`manus.adaptive.slotine_li.rollout_batch`).

`summarize` reports per parameter: the truth, the final estimate (mean over trials) and its
spread, the relative error of that mean, and t_within_5pct: the median over trials of the time
after which the estimate stays within 5 % of the truth (null when fewer than half the trials get
there). Beside them, the excitation the adaptation saw: the smallest eigenvalue of ∫YᵀY dt.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

TRAJECTORIES = ("complex", "benign", "multisine")
EVERY = 50  # ticks between checkpoints of the excitation ∫YᵀY
RECORD = 10  # ticks between the recorded rows of the figures (the statistics cover every tick)


class Trials(NamedTuple):
    """A batch of trials, numpy arrays with a leading trial axis B. The statistics (final
    estimates, settle times, tracking error, largest command) cover every tick; the rows for the
    figures are every `RECORD`-th tick's."""

    t: np.ndarray  # times of the recorded ticks (T,)
    q_err: np.ndarray  # q − q_d (B, T, n)
    tau: np.ndarray  # commands (B, T, n)
    theta: np.ndarray  # estimates (B, T, P)
    t_gram: np.ndarray  # checkpoint times (C,)
    grams: np.ndarray  # ∫₀ᵗ YᵀY dt at the checkpoints (B, C, P, P)
    stopped: np.ndarray  # a trial's controller stopped itself (B,)
    names: tuple
    truth: np.ndarray  # (P,)
    theta_final: np.ndarray  # estimates after the last tick (B, P)
    q_err_ms: np.ndarray  # mean of (q − q_d)² over every tick (B, n)
    tau_max: np.ndarray  # largest |τ| over every tick (B, n)
    settle: np.ndarray  # time after which the estimate stays within 5 % of the truth, NaN never (B, P)

    @property
    def lam_min(self) -> np.ndarray:
        """The smallest eigenvalue of ∫₀ᵗ YᵀY at every checkpoint (B, C)."""
        return np.linalg.eigvalsh(self.grams)[..., 0]


def trajectory(name: str, model):
    """The reference of a trial: the thesis's benign or complex trajectory (the manus2 arm's), or
    a multi-sine about the workspace centre of `model`."""
    from manus.plants.references import reference_named
    from manus.plants.simulator import workspace_centre

    return reference_named(name, np.asarray(workspace_centre(model)), model.structure.thesis_arm)


def controller_for(plant, model, law: str, estimator, form: str = "slotine-li", uncompensated=False, **gains):
    """The Slotine–Li controller of a trial; timing compensated for the plant's known delay
    unless told otherwise; `gains` as for `manus.adaptive.make_controller`."""
    from manus.adaptive.controllers import make_controller, make_estimator

    if isinstance(estimator, str):
        knobs = {} if plant.encoder is None else {"step": plant.encoder.step}  # the Kalman filters want it
        if estimator in ("kalman_cv", "kalman_ca"):  # they start at their steady state: the same estimates
            knobs["steady"] = True  # to rounding (5e-14) with the constant gain, 11 ns less per trial-step
        estimator = make_estimator(estimator, plant.dt, model, **knobs)
    knobs = {"lead": 0.0, "velocity_lag": 0.0} if uncompensated else {"lead": 0.5 * plant.dt + plant.delay}
    if plant.actuator is not None:
        knobs["limit"] = plant.actuator.limit
    elif plant.model.structure.name == "urdf":  # a serial robot: the torque it is commanded, no D/A's limit
        knobs["limit"] = float("inf")
    name = "slotine-li-composite" if law == "composite" else "slotine-li"
    return make_controller(name, model, plant.dt, estimator, form=form, **{**knobs, **gains})


def run_trials(
    plant, controller, reference, trials: int, seconds: float, init_spread=0.5, gain_spread=0.25, seed=0, record=RECORD
) -> Trials:
    """`trials` closed-loop runs of `controller` on `plant`, vmapped (see the module docstring)."""
    import jax
    import jax.numpy as jnp

    from manus.adaptive.slotine_li import rollout_batch
    from manus.plants.errors import ManusError

    mine, theirs = controller.regressor.model.structure, plant.model.structure
    if controller.n_joints != plant.model.n_joints or mine.name != theirs.name:
        raise ManusError(
            f"the controller's model ({mine.name}, {controller.n_joints} joints) does not match "
            f"the plant ({theirs.name}, {plant.model.n_joints} joints)"
        )
    if trials < 1 or seconds <= 0 or not 0 <= init_spread < 1 or gain_spread < 0:
        raise ManusError("need trials >= 1, seconds > 0, 0 <= init-spread < 1 and gain-spread >= 0")
    steps = EVERY * max(1, int(round(seconds / plant.dt / EVERY)))
    rng = np.random.default_rng(seed)
    g = np.log1p(gain_spread)
    theta0 = np.asarray(controller.theta0) * rng.uniform(
        1 - init_spread, 1 + init_spread, (trials, len(controller.names))
    )
    arrays = (
        jnp.asarray(theta0),
        *(
            jnp.asarray(np.asarray(x) * np.exp(rng.uniform(-g, g, (trials,) + x.shape)))
            for x in (controller.gamma, controller.lam, controller.kd)
        ),
    )
    keys = jax.random.split(jax.random.PRNGKey(seed), trials)
    known = dict(plant.params)
    if (
        theirs.standard_form is theirs
    ):  # the truth in the coordinates the controller adapts in (a chain's pseudo-inertia)
        known.update(mine.coordinates_of(plant.params))
    truth = np.array([float(known.get(k, 0.0)) for k in controller.names])
    log = rollout_batch(plant, controller, reference, arrays, keys, steps, EVERY, record, truth)
    return Trials(
        log.t,
        log.q_err,
        log.tau,
        log.theta,
        (np.arange(steps // EVERY) + 1) * EVERY * plant.dt,
        log.grams,
        log.stopped,
        tuple(controller.names),
        truth,
        log.theta_final,
        log.q_err_ms,
        log.tau_max,
        log.settle,
    )


def settle_times(t: np.ndarray, theta: np.ndarray, truth: float, tol: float = 0.05) -> np.ndarray:
    """Per trial, the time after which |θ − truth| ≤ tol |truth| for good (NaN: never), from a
    record of every tick (the batch keeps this statistic as it runs: `Trials.settle`)."""
    outside = np.abs(theta - truth) > tol * abs(truth)  # (B, T)
    last = np.where(outside.any(1), outside.shape[1] - 1 - np.argmax(outside[:, ::-1], 1), -1)
    times = np.where(last + 1 < len(t), t[np.minimum(last + 1, len(t) - 1)], np.nan)
    return np.where(outside[:, -1], np.nan, times)


def summarize(tr: Trials) -> dict:
    """Per-parameter figures (docs/cli.md) and the excitation."""
    ok = ~tr.stopped
    params = {}
    for i, name in enumerate(tr.names):
        final = tr.theta_final[ok, i]
        truth = float(tr.truth[i])
        mean = float(final.mean())
        entry: dict[str, float | None] = {"truth": truth, "final": mean, "final_std": float(final.std())}
        if truth != 0:
            settle = tr.settle[ok, i]
            settled = float(np.mean(np.isfinite(settle)))
            entry["error"] = (mean - truth) / abs(truth)
            entry["settled"] = settled
            entry["t_within_5pct"] = float(np.nanmedian(settle)) if settled >= 0.5 else None
        else:  # not in the plant: only an absolute figure means something
            entry.update(error=None, settled=None, t_within_5pct=None)
        params[name] = entry
    # the smallest eigenvalue of ∫YᵀY at the end and after 1 s only (`Trials.lam_min` has them all)
    at = [len(tr.t_gram) - 1] + ([int(np.searchsorted(tr.t_gram, 1.0 - 1e-9))] if tr.t_gram[-1] >= 1 else [])
    lam = np.linalg.eigvalsh(tr.grams[ok][:, at])[..., 0]
    return {
        "params": params,
        "trials": int(len(tr.stopped)),
        "stopped_trials": int(tr.stopped.sum()),
        "excitation": {
            "lambda_min": float(np.mean(lam[:, 0])),
            "lambda_min_at_1s": float(np.mean(lam[:, 1])) if len(at) > 1 else None,
        },
        "tracking_rms": np.sqrt(np.mean(tr.q_err_ms[ok], axis=0)).tolist(),
        "tau_max": tr.tau_max[ok].max(axis=0).tolist(),
    }


def base_summary(tr: Trials, pseudo) -> dict:
    """A serial chain adapted in pseudo-inertia coordinates: its base parameters (K φ, the
    combinations the torque determines; `SerialBase`) from the final estimates, beside the truth's."""
    base = pseudo.serial.base()
    ok = ~tr.stopped
    names = list(tr.names)

    def based(theta):
        p = dict(zip(names, theta, strict=True))
        return base.values(np.asarray(pseudo.standard({k: p[k] for k in pseudo.rigid_names})))

    truth = based(tr.truth)
    finals = np.array([based(t) for t in tr.theta_final[ok]])
    out = {}
    for i, name in enumerate(base.base_names):
        f = finals[:, i]
        err = float((f.mean() - truth[i]) / abs(truth[i])) if abs(truth[i]) > 1e-12 else None
        out[name] = {"truth": float(truth[i]), "final": float(f.mean()), "final_std": float(f.std()), "error": err}
    return out
