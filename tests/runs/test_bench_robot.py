"""`manus bench robot` on tiny sizes: the JSON contract, and JAX's regressor is pinocchio's."""

import json

import pytest

from manus.runs.cli import main

pytest.importorskip("pinocchio")


def test_bench_robot_reports_rows_per_second_beside_pinocchio(capsys):
    code = main(["bench", "robot", "--states", "20", "--pinocchio-states", "5", "--repeats", "1", "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    r = json.loads(captured.out)
    assert set(r["figures"]) == {"jax_rows_per_s", "pinocchio_rows_per_s", "jax_compile_s"}
    assert r["speedup"] == r["figures"]["jax_rows_per_s"] / r["figures"]["pinocchio_rows_per_s"]
    assert r["joints"] == 7 and r["columns"] == 77 and r["agreement"] < 1e-9


def test_bench_robot_refuses_bad_sizes(capsys):
    assert main(["bench", "robot", "--states", "0"]) == 2
    assert "must be positive" in capsys.readouterr().err
