"""What the parameter-convergence trials must show (thesis App. C), on small batches of 4-s trials
with different initial estimates, gains and noise seeds: the benign trajectory does not
determine the parameters, the complex one does; friction in the plant biases a rigid-only model
by several percent and a friction-augmented one removes the bias; composite adaptation converges
faster than the gradient law on the same trials."""

import contextlib
import io
import json

import pytest

from manus.experiments import convergence
from manus.experiments.convergence import controller_for, run_trials, summarize
from manus.plants import Model, Simulator
from manus.plants.structures import Manus2
from manus.runs.cli import main

TRUTH = "rigid,viscous,coulomb"
RIGID = ("a1", "a2", "a3")


def trials(model, law="gradient", trajectory="complex", n=12, estimator="kalman_cv"):
    plant = Simulator(Model(Manus2(), TRUTH), torque_noise=0.005)
    model = Model(Manus2(), model)
    controller = controller_for(plant, model, law, estimator)
    tr = run_trials(plant, controller, convergence.trajectory(trajectory, model), n, 4.0)
    return tr, summarize(tr)


def converge(*args):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["converge", *args])
    return code, out.getvalue()


@pytest.fixture(scope="module")
def rigid_only(tmp_path_factory):
    """The command's own run, with its defaults (truth rigid,viscous,coulomb, kalman_cv, 4 s)."""
    out = tmp_path_factory.mktemp("converge")
    code, text = converge("--trials", "6", "--model", "rigid", "--json", "--out", str(out))
    assert code == 0
    return json.loads(text), out  # nothing but the JSON object on stdout


@pytest.fixture(scope="module")
def augmented():
    return trials(TRUTH)


@pytest.fixture(scope="module")
def composite():
    return trials(TRUTH, "composite")


def test_friction_in_the_plant_biases_a_rigid_only_model_by_several_percent(rigid_only):
    s, _ = rigid_only
    for name in RIGID:
        p = s["params"][name]
        assert -0.15 < p["error"] < -0.03, (name, p)  # several percent low
        assert p["final_std"] < abs(p["error"]) * p["truth"] / 3  # every trial there: converged, wrongly


def test_the_friction_augmented_regressor_removes_the_bias(augmented, composite):
    for name in RIGID:  # the gradient law: the inertias within 2 % (its friction split is slow)
        assert abs(augmented[1]["params"][name]["error"]) < 0.02
    for name, p in composite[1]["params"].items():  # composite: every parameter within 2 %
        assert abs(p["error"]) < 0.02, (name, p)
        assert p["t_within_5pct"] is not None and p["t_within_5pct"] < 3.0, (name, p)


def test_composite_adaptation_converges_faster_than_the_gradient_law_on_the_same_trials(augmented, composite):
    """Same seed: the same initial estimates, gains and noise in both batches."""
    plain, comp = augmented[1]["params"], composite[1]["params"]
    for name in plain:
        t_plain = plain[name]["t_within_5pct"]
        assert comp[name]["t_within_5pct"] < (4.0 if t_plain is None else t_plain), name


def test_the_benign_trajectory_does_not_determine_the_parameters(rigid_only):
    _, s = trials("rigid", trajectory="benign", n=6)
    assert s["excitation"]["lambda_min"] < 0.01 * rigid_only[0]["excitation"]["lambda_min"]
    # the estimates wander: they end where their different starts and gains left them
    assert max(p["final_std"] / p["truth"] for p in s["params"].values()) > 0.05
    assert all(p["t_within_5pct"] is None for p in s["params"].values())


def test_the_command_keeps_the_json_contract_and_draws_the_figures(rigid_only):
    s, out = rigid_only
    assert set(s["params"]) == set(RIGID) and s["trials"] == 6 and s["stopped_trials"] == 0
    for p in s["params"].values():
        assert {"truth", "final", "t_within_5pct"} <= set(p)
    assert s["params"]["a1"]["truth"] == 0.349
    assert s["estimator"] == "kalman_cv" and s["velocity_lag_s"] > 0.001
    for path in s["figures"].values():
        assert (out / path.split("/")[-1]).stat().st_size > 20000


def test_bad_gains_and_trial_settings_fail_before_the_run(tmp_path, capsys):
    assert converge("--trials", "2", "--gain", "kd=-1", "--out", str(tmp_path))[0] == 2
    assert "kd must be positive definite" in capsys.readouterr().err
    assert converge("--trials", "0", "--out", str(tmp_path))[0] == 2
    assert converge("--structure", "axis", "--trajectory", "complex", "--out", str(tmp_path))[0] == 2
    assert "complex trajectory is the thesis's for the manus2 arm" in capsys.readouterr().err


def test_the_velocity_estimator_changes_what_composite_adaptation_converges_to(composite):
    """The prediction error sees the estimator's noise and lag: with the plain first difference
    (quantization noise, half a period of lag) the friction estimates end biased by several
    percent; with the Kalman filter every parameter is within 2 % (the test above)."""
    _, fd = trials(TRUTH, "composite", n=6, estimator="first_difference")
    worst = max(abs(p["error"]) for p in fd["params"].values())
    best = max(abs(p["error"]) for p in composite[1]["params"].values())
    assert worst > 0.05 and worst > 3 * best, (worst, best)
