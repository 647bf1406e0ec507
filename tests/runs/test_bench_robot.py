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
            "--arm-seconds",
            "0",
            "--ur5-seconds",
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
            "--arm-seconds",
            "0",
            "--ur5-seconds",
            "0",
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


def test_the_baseline_is_least_squares_on_pinocchios_regressor():
    """The baseline on a simulated Panda (0.3 s at 1 kHz, noiseless): pinocchio's regressor at
    every sample with friction and offset columns fits the simulated torque to about a percent
    (the command is held over each period and q̈ is a difference: not exact), and its rows are
    the samples."""
    import jax

    from manus.plants.serial_sim import record
    from manus.runs.bench.robot import PANDA, _urdf, baseline, panda_case

    path = _urdf(PANDA)
    with jax.enable_x64(True):
        serial, sim, reference, _ = panda_case(path)
        rec = record(sim, reference, 0.3)
    b = baseline(path, serial, rec)
    assert b["rows"] == len(rec) == 300
    assert b["rel_error"] < 0.05 and b["s"] > 0


def test_bench_robot_refuses_unknown_commands(capsys):
    argv = ["bench", "robot", "--states", "2", "--pinocchio-states", "1", "--repeats", "1", "--fit-seconds", "0"]
    assert main([*argv, "--commands", "fit,simulate"]) == 2
    assert "unknown simulate" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_robot_times_manus_fit_in_a_new_process(capsys):
    """`manus fit` on a 3 s Panda recording, in a new process, beside the baseline."""
    argv = ["bench", "robot", "--states", "2", "--pinocchio-states", "1", "--repeats", "1", "--fit-seconds", "0"]
    code = main([*argv, "--arm-seconds", "3", "--ur5-seconds", "0", "--commands", "fit", "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    (arm,) = json.loads(captured.out)["arms"]
    assert arm["robot"] == "panda" and arm["joints"] == 7 and arm["fit"]["s"] > 0 and arm["fit"]["cpu_s"] > 0
    assert arm["fit"]["rel_error"] < 0.01 and arm["baseline"]["rows"] == 3000
