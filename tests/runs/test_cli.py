"""The `manus` command's contract: --json prints one object on stdout; errors are one line."""

import importlib.metadata
import json
import subprocess
import sys

import numpy as np
import pytest

from manus.plants import recording
from manus.runs.cli import main


def test_simulate_writes_a_readable_recording_with_truth(tmp_path, capsys):
    out = tmp_path / "rec.csv"
    code = main(["simulate", "--truth", "rigid,viscous,coulomb,cogging", "--seconds", "1", "--out", str(out), "--json"])
    captured = capsys.readouterr()
    assert code == 0
    result = json.loads(captured.out)  # nothing else on stdout
    assert result["recording"] == str(out) and result["samples"] == 1000
    assert result["truth"] == "rigid,viscous,coulomb,cogging:39"
    rec = recording.read(out)
    assert rec.has_truth and rec.n_joints == 2 and rec.meta["truth"] == result["truth"]
    assert (tmp_path / "rec.png").stat().st_size > 10000
    assert np.all(np.abs(rec.q - np.stack([rec.extra["qref1"], rec.extra["qref2"]], 1)) < 0.1)


def test_errors_are_one_line_and_non_zero(tmp_path, capsys):
    code = main(["simulate", "--truth", "rigid,glue", "--out", str(tmp_path / "x.csv")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err
    assert err.startswith("manus simulate: unknown effect 'glue'")
    code = main(["simulate", "--param", "Fc9=1", "--out", str(tmp_path / "x.csv")])
    assert code == 2 and "unknown parameter(s) Fc9" in capsys.readouterr().err


def test_a_plant_that_breaks_physics_is_refused_by_name(tmp_path, capsys):
    """Options that describe no physical plant: one line naming the rule, no simulation."""
    for argv, message in (
        (["--param", "a1=-1"], "H(q) is not positive definite"),
        (["--param", "b2=-0.1"], "viscous friction dissipates"),
        (["--structure", "axis", "--joints", "0"], "at least one joint"),
        (["--torque-noise", "-1"], "neither can be negative"),
    ):
        code = main(["simulate", *argv, "--seconds", "0.1", "--out", str(tmp_path / "x.csv")])
        err = capsys.readouterr().err.strip()
        assert code == 2 and "\n" not in err and message in err, err
    assert not (tmp_path / "x.csv").exists()


def test_a_fixed_model_with_several_values_is_rendered(tmp_path, capsys):
    """Fixed non-linear parameters with several values (two cogging orders, a delay per joint)
    are printed, not an internal error."""
    out = tmp_path / "rec.csv"
    assert main(["simulate", "--seconds", "2", "--out", str(out), "--json"]) == 0
    capsys.readouterr()
    assert main(["fit", "--model", "rigid,viscous,coulomb,cogging:39+6,delay:1ms/2ms", str(out), "--no-figures"]) == 0
    text = capsys.readouterr().out
    assert "orders = 39, 6" in text and "delay_ms = 1, 2" in text


def test_what_was_done_to_a_recording_as_it_was_read_is_one_line(tmp_path, capsys):
    """A revolute angle recorded in [−π, π) (it swings about π): unwrapped, said as one note line on
    stderr, not a Python warning with its source line; the fit then runs on the unwrapped angle."""
    import numpy as np

    from manus.plants import recording

    out = tmp_path / "rec.csv"
    assert main(["simulate", "--seconds", "2", "--out", str(out), "--json"]) == 0
    capsys.readouterr()
    rec = recording.read(out)
    swing = rec.q[:, 1] - np.median(rec.q[:, 1]) + np.pi  # joint 2 moved to swing about π ...
    rec.q[:, 1] = (swing + np.pi) % (2 * np.pi) - np.pi  # ... and written in [−π, π)
    wrapped = recording.write(rec, tmp_path / "wrapped.csv")
    assert main(["fit", "--model", "rigid,viscous,coulomb", str(wrapped), "--no-figures", "--json"]) == 0
    err = capsys.readouterr().err
    assert "manus fit: note: " in err and "q2 wraps" in err and "unwrapped" in err and "Warning" not in err, err


def test_version_is_the_installed_one(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"manus {importlib.metadata.version('manus')}"


def test_importing_the_command_sets_no_environment(tmp_path):
    """The environment numpy and JAX read (threads, XLA flags) is set when `main` runs, not on import."""
    code = "import os; before = dict(os.environ); import manus.runs.cli; print(dict(os.environ) == before)"
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "True"


def test_a_dead_link_is_a_one_line_error(tmp_path):
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "manus.runs.cli",
            "run-hardware",
            "--device",
            "udp://127.0.0.1:9",
            "--seconds",
            "1",
            "--json",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.strip().splitlines() == [
        "manus run-hardware: udp://127.0.0.1:9: no answer from the device within 2 s "
        "(is `manus emulate --port 9` or the rig running?)"
    ]


def test_the_executable_ends_as_any_exit_would(tmp_path):
    """`entry` leaves without the interpreter's teardown, but its output is whole, its threads
    finish, its exit handlers run and its exit code is main's."""
    code = f"""
import atexit, sys, threading, time
from manus.runs import cli
atexit.register(lambda: open({str(tmp_path / "atexit")!r}, "w").write("ran"))
threading.Thread(target=lambda: (time.sleep(0.5), open({str(tmp_path / "thread")!r}, "w").write("done"))).start()
sys.argv = ["manus"] + sys.argv[1:]
cli.entry()
"""
    rec = tmp_path / "r.csv"
    ok = subprocess.run(
        [sys.executable, "-c", code, "simulate", "--seconds", "0.5", "--out", str(rec), "--json"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert ok.returncode == 0, ok.stderr[-2000:]
    assert json.loads(ok.stdout)["samples"] == 500
    assert (tmp_path / "atexit").read_text() == "ran" and (tmp_path / "thread").read_text() == "done"
    bad = subprocess.run(
        [sys.executable, "-c", code, "fit", str(tmp_path / "none.csv"), "--model", "rigid"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert bad.returncode == 2 and bad.stderr.strip().endswith("none.csv: no such file")
