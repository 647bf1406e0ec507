"""`manus bench converge` on tiny sizes: the JSON contract (no timing asserts), bad sizes refused."""

import json

from manus.runs.cli import main


def test_bench_converge_reports_the_batch_beside_the_loops_and_the_bare_plant(capsys):
    code = main(
        [
            "bench",
            "converge",
            "--trials",
            "4",
            "--seconds",
            "0.05",
            "--sample",
            "1",
            "--tick-sample",
            "0.01",
            "--repeats",
            "1",
            "--json",
        ]
    )
    captured = capsys.readouterr()
    assert code == 0, captured.err
    r = json.loads(captured.out)
    f = r["figures"]
    assert set(f) >= {
        "batch_trial_steps_per_s",
        "batch_cpu_ns_per_trial_step",
        "scan_loop_trial_steps_per_s",
        "scan_loop_trials_per_s",
        "tick_loop_trials_per_s",
        "bare_plant_batch_trial_steps_per_s",
        "bare_plant_batch_every_100_trial_steps_per_s",
        "scan_loop_cpu_ns_per_step",
        "bare_plant_batch_cpu_ns_per_trial_step",
        "batch_trial_steps_per_s_idle",
    }
    assert all(v > 0 for k, v in f.items() if not k.endswith("compile_s"))
    assert r["speedup"] > 0 and r["of_bare_plant"] > 0 and r["trials"] == 4 and r["devices"] >= 1
    assert r["speedup_cpu"] > 0 and "load_average" in r and r["cores"] >= 1
    assert r["seconds"] == 0.05 and r["bare_plant"] == "rigid,viscous,coulomb,delay"


def test_bench_converge_refuses_bad_sizes(capsys):
    assert main(["bench", "converge", "--trials", "0"]) == 2
    assert "need --trials" in capsys.readouterr().err.strip()
