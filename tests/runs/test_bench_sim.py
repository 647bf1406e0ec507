"""`manus bench sim` on tiny sizes: the JSON contract, and the numpy baseline is the same model."""

import json

from manus.runs.cli import main


def test_bench_sim_reports_its_figures_beside_a_numpy_loop_of_the_same_model(capsys):
    code = main(
        [
            "bench",
            "sim",
            "--trials",
            "2",
            "--seconds",
            "0.03",
            "--numpy-seconds",
            "0.03",
            "--every",
            "1",
            "--repeats",
            "1",
            "--json",
        ]
    )  # --every 1: one batch compilation
    captured = capsys.readouterr()
    assert code == 0, captured.err
    r = json.loads(captured.out)
    f = r["figures"]
    assert set(f) >= {
        "single_trial_steps_per_s",
        "batch_trial_steps_per_s",
        "numpy_steps_per_s",
        "batch_full_record_trial_steps_per_s",
    }
    assert all(v > 0 for v in f.values())
    assert r["speedup"] == f["batch_trial_steps_per_s"] / f["numpy_steps_per_s"]
    assert r["dtype"] == "float64" and r["trials"] == 2 and r["substeps"] == 10
    # the numpy loop reproduces the simulator's measured positions count for count
    assert r["agreement_counts"] == 0


def test_bench_sim_refuses_bad_sizes(capsys):
    assert main(["bench", "sim", "--trials", "0"]) == 2
    assert "must be positive" in capsys.readouterr().err
