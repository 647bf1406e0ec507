"""`manus bench robot` on tiny sizes: the JSON contract, and JAX's regressor is pinocchio's."""

import json

import pytest

from manus.runs.cli import main

pytest.importorskip("pinocchio")


def test_bench_robot_reports_rows_per_second_beside_pinocchio(capsys):
    code = main(
        [
            "bench",
            "robot",
            "--states",
            "20",
            "--pinocchio-states",
            "5",
            "--repeats",
            "1",
            "--fit-seconds",
            "0",
            "--json",
        ]
    )
    captured = capsys.readouterr()
    assert code == 0, captured.err
    r = json.loads(captured.out)
    assert set(r["figures"]) == {"jax_rows_per_s", "pinocchio_rows_per_s", "jax_compile_s"}
    assert r["speedup"] == r["figures"]["jax_rows_per_s"] / r["figures"]["pinocchio_rows_per_s"]
    assert r["joints"] == 7 and r["columns"] == 77 and r["agreement"] < 1e-9


def test_bench_robot_times_the_simulated_panda_and_its_fit(capsys):
    """The loop's figures on tiny sizes: 2 s simulated, fitted; a batch of 2 trials of 50 ms."""
    code = main(
        [
            "bench",
            "robot",
            "--states",
            "4",
            "--pinocchio-states",
            "2",
            "--repeats",
            "1",
            "--fit-seconds",
            "2",
            "--trials",
            "2",
            "--batch-seconds",
            "0.05",
            "--json",
        ]
    )
    captured = capsys.readouterr()
    assert code == 0, captured.err
    f = json.loads(captured.out)["figures"]
    assert f["simulate_one_trial_steps_per_s"] > 0 and f["batch_trial_steps_per_s"] > 0 and f["fit_s"] > 0
    assert f["fit_rel_error"] < 0.01  # the truth's own model on a noiseless simulation
    assert f["base_carrying"] > 0 and f["diagnose_s"] > 0 and "diagnose_verdict" in f


def test_bench_robot_refuses_bad_sizes(capsys):
    assert main(["bench", "robot", "--states", "0"]) == 2
    assert "must be positive" in capsys.readouterr().err
    assert main(["bench", "robot", "--trials", "0", "--states", "2", "--pinocchio-states", "1", "--repeats", "1"]) == 2
    assert "must be positive" in capsys.readouterr().err
