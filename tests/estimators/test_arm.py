"""On a simulated, quantized recording of the arm (131072 counts/rev, 1 kHz, motion up to 5 Hz
then holding still): the Kalman filter against the thesis's estimator, tuning, model-based
estimators and their parameters in the state."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus import estimators
from manus.estimators.compare import Setup, reference_velocity, run_estimator, tune
from manus.estimators.kalman import KinematicKalman
from manus.estimators.model_kalman import ModelKalman
from manus.plants import Manus2, Model


def test_kalman_ca_is_5x_better_than_the_thesis_filter_at_under_1ms(arm_recording, arm_report):
    rec, (report, est) = arm_recording, arm_report
    rows = {r["name"]: r for r in report["estimators"]}
    ffd, ca = rows["filtered_first_difference"], rows["kalman_ca"]
    assert tuple(rows) == estimators.NAMES and report["best"] in ("kalman_model", "luenberger_model")
    assert report["truth"] and report["step"] == {"value": pytest.approx(2 * np.pi / 131072), "source": "metadata"}
    assert ffd["rms_error"] / ca["rms_error"] >= 5  # the issue expects about 10x
    assert abs(ca["lag_ms"]) < 1.0
    assert ffd["lag_ms"] == pytest.approx(1e3 / 188.5, abs=0.3)  # a first-order lag of time constant 1/λ
    # the report's numbers, recomputed from the estimates by hand
    assert rec.qd is not None
    start, stop = report["scored_samples"]
    err = est["kalman_ca"][start:stop] - rec.qd[start:stop]
    still = np.abs(rec.qd[start:stop]) < 0.02 * np.percentile(np.abs(rec.qd[start:stop]), 99, axis=0)
    assert 0.1 < still.mean() < 0.5  # the recording holds still for its last second
    assert ca["rms_error"] == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-12)
    assert ca["still"]["rms_error"] == pytest.approx(np.sqrt(np.mean(err[still] ** 2)), rel=1e-12)
    assert ca["moving"]["max_error"] == pytest.approx(np.abs(err[~still]).max(), rel=1e-12)
    assert ca["noise_50hz"] < ffd["rms_error"] / 5


def test_tuning_against_truth_and_without_it(arm_recording):
    rec = arm_recording
    setup = Setup(rec.dt, 2 * np.pi / 131072, 2)
    ref, _, start, stop = reference_velocity(rec, 30.0)
    rms = lambda knob: np.sqrt(
        np.mean((run_estimator(setup.make("kalman_ca", q=knob), rec.q, rec.tau).qd[start:stop] - ref[start:stop]) ** 2)
    )
    kalman = setup.make("kalman_ca")
    assert isinstance(kalman, KinematicKalman)
    default = float(kalman.q)
    by_truth = tune(setup, "kalman_ca", rec.q, rec.tau, ref, start, stop)
    blind = tune(setup, "kalman_ca", rec.q, rec.tau, None, start, stop)
    assert by_truth is not None and blind is not None
    assert by_truth["criterion"] == "rms_error" and blind["criterion"] == "whiteness"
    assert by_truth["objective"] == pytest.approx(rms(by_truth["value"]), rel=1e-9)
    assert by_truth["objective"] < rms(default)
    # a knob found without the truth is nearly as good as one found with it
    assert rms(blind["value"]) < 1.5 * by_truth["objective"]
    assert 0.1 < blind["value"] / by_truth["value"] < 10


def test_model_based_estimators_use_the_model_and_take_new_parameters(arm_recording, arm_report):
    rec = arm_recording
    rms = {r["name"]: r["rms_error"] for r in arm_report[0]["estimators"]}
    assert rms["kalman_model"] < rms["kalman_ca"] / 1.5  # the model predicts the acceleration
    assert rms["luenberger_model"] < rms["luenberger"] / 5  # same gains, with and without the model

    # the model's delay effect: the torque of one sample earlier, exactly
    delayed = estimators.make("luenberger_model", model=Model(Manus2(), "rigid,viscous,coulomb,delay:1ms"))
    shifted = np.vstack([np.zeros((1, 2)), rec.tau[:-1]])
    np.testing.assert_array_equal(
        run_estimator(delayed, rec.q, rec.tau).qd, run_estimator(estimators.make("luenberger_model"), rec.q, shifted).qd
    )

    est = estimators.make("kalman_model", n_joints=2)
    assert isinstance(est, ModelKalman) and est.dynamics is not None
    wrong = est.with_params(est.init(jnp.asarray(rec.q[0])), {"a1": 0.7, "a3": 0.5})
    assert float(est.params(wrong)["a1"]) == 0.7 and float(est.params(wrong)["b1"]) == 0.222

    @eqx.filter_jit
    def replay(state, theta):
        """What an adaptive controller does: hand the estimator its parameters every tick."""

        def tick(s, x):
            s, e = est.step(est.with_params(s, theta), *x)
            return s, e.qd

        tau_prev = jnp.concatenate([jnp.zeros((1, 2)), jnp.asarray(rec.tau[:-1])])
        return jax.lax.scan(tick, state, (jnp.asarray(rec.q), tau_prev))[1]

    error = lambda theta: np.sqrt(np.mean((np.asarray(replay(wrong, theta)) - rec.qd)[100:] ** 2))
    right = est.dynamics.theta(None)
    bad = right.at[0].set(0.7).at[2].set(0.5)
    assert error(right) < error(bad) / 2
    assert error(right) == pytest.approx(rms["kalman_model"], rel=0.1)


def test_acceleration_estimates(arm_recording, arm_report):
    """q̈ from the constant-acceleration filter and the model-based ones, against the derivative
    of the true velocity while moving (the hold's stick-slip jumps excluded)."""
    rec = arm_recording
    assert rec.qd is not None
    truth = np.gradient(rec.qd, rec.dt, axis=0)[100:2400]

    def relative(name):
        qdd = run_estimator(estimators.make(name), rec.q, rec.tau).qdd
        assert qdd is not None
        return np.sqrt(np.mean((qdd[100:2400] - truth) ** 2) / np.mean(truth**2))

    assert relative("kalman_ca") < 0.3
    assert relative("kalman_model") < 0.05


def test_a_model_based_estimator_applies_each_joints_own_delay():
    """With a delay per joint (1 and 3 samples), the torque acting now is each joint's command
    from its own number of periods ago."""
    from manus.estimators.dynamics import ModelDynamics

    dyn = ModelDynamics(Model(Manus2(), "rigid,viscous,delay:1ms/3ms"), dt=1e-3)
    history = dyn.commands(2)
    assert history is not None and history.shape == (3, 2)
    acting = []
    for k in range(1, 7):  # commands k, -k on the two joints
        tau, history = dyn.acting(history, jnp.array([k, -k], float), 2)
        acting.append(np.asarray(tau))
    np.testing.assert_array_equal(np.array(acting), [[0, 0], [1, 0], [2, 0], [3, -1], [4, -2], [5, -3]])


def test_samples_lost_in_a_gap_are_filled_before_the_estimators_run(arm_recording, arm_report):
    """20 samples missing at 1.5 s, mid-motion: each estimator is scored as on the whole recording
    (read as uniform, the jump in position is a velocity spike of ~0.3 rad/s in every estimate),
    and the report says so."""
    from manus.estimators.compare import compare

    rec, keep = arm_recording, np.ones(len(arm_recording), bool)
    keep[1500:1520] = False
    gapped = rec.rows(keep)
    report, est = compare(gapped, ("filtered_first_difference", "kalman_ca"))
    assert report["gaps"].startswith("20 samples lost in 1 gap") and len(est["kalman_ca"]) == len(rec)
    whole = {r["name"]: r for r in arm_report[0]["estimators"]}
    for row in report["estimators"]:
        assert row["rms_error"] == pytest.approx(whole[row["name"]]["rms_error"], rel=0.1), row["name"]
