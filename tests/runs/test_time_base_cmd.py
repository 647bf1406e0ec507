"""The commands on a recording whose time base a PC logger blurred (repeated rows, jittered stamps):
one line on stderr says what was found and done, the JSON carries a `time_base` object; on the
clean recording neither. `rel_error_per_joint` (fit, diagnose, discover) is the per-joint
‖τ_j − τ̂_j‖ / ‖τ_j‖ of the fitted parameters, over the rows of rel_error."""

import json

import numpy as np
import pytest

from manus.adaptive import Columns, fit
from manus.experiments.calibration import case
from manus.plants import recording
from manus.runs.cli import main
from tests.plants.test_timebase import jitter_stamps, repeat_rows

MODEL = "rigid,viscous,coulomb"
KEYS = {"rate_hz", "repeated_rows", "jitter", "held_rows", "repaired", "note"}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The arm reaching at 1 kHz (calibration seed 5, nothing hidden): clean, and with 5 % of its
    moving rows repeated and its stamps jittered by ±20 % of the period."""
    rec = case(5, None, rates=(1000,)).rec
    folder = tmp_path_factory.mktemp("time_base")
    rng = np.random.default_rng(5)
    blurred = jitter_stamps(repeat_rows(rec, 0.05, rng)[0], 0.2, rng)
    return recording.write(rec, folder / "clean.csv"), recording.write(blurred, folder / "blurred.csv")


def _run(capsys, argv):
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out), captured.err


COMMANDS = {
    "fit": ["--model", MODEL, "--no-figures"],
    "diagnose": ["--model", MODEL, "--no-figures"],
    "discover": ["--model", MODEL, "--no-figures", "--max-steps", "1"],
    "estimators": ["--no-figures", "--only", "first_difference,kalman_cv"],
}


@pytest.mark.slow
@pytest.mark.parametrize("command", COMMANDS)
def test_a_blurred_time_base_is_said_and_reported(capsys, files, command):
    clean, blurred = files
    r, err = _run(capsys, [command, str(blurred), "--json", *COMMANDS[command]])
    tb = r["time_base"]
    assert set(tb) == KEYS and tb["repaired"] is True and tb["repeated_rows"] > 400 and tb["held_rows"] == 0
    assert 0.1 < tb["jitter"] < 0.13 and tb["rate_hz"] == pytest.approx(1000, rel=1e-4)
    lines = [line for line in err.splitlines() if "time base:" in line]
    assert len(lines) == 1 and lines[0].startswith(f"manus {command}: note: {blurred}: time base: ")
    assert "repeated rows" in lines[0] and "stamps scatter" in lines[0]
    r, err = _run(capsys, [command, str(clean), "--json", *COMMANDS[command]])
    assert "time_base" not in r and "time base" not in err


def test_fit_reports_rel_error_per_joint_of_its_parameters(capsys, files):
    clean, _ = files
    r, _ = _run(capsys, ["fit", str(clean), "--json", *COMMANDS["fit"]])
    f = fit(recording.read(clean), MODEL)
    theta = np.array([r["params"][k]["value"] for k in f.names])
    Y = Columns(f.data).model(f.model)  # (rows, n, P)
    tau = f.data.tau(f.delay)
    per_joint = np.linalg.norm(tau - Y @ theta, axis=0) / np.linalg.norm(tau, axis=0)
    assert len(r["rel_error_per_joint"]) == 2
    assert np.allclose(r["rel_error_per_joint"], per_joint, rtol=1e-9, atol=0)
    # the joints' errors make up the whole: Σ e_j² ‖τ_j‖² = e² ‖τ‖²
    whole = np.sqrt(np.sum((per_joint * np.linalg.norm(tau, axis=0)) ** 2)) / np.linalg.norm(tau)
    assert whole == pytest.approx(r["rel_error"], rel=1e-9)


@pytest.mark.slow
def test_diagnose_and_discover_report_rel_error_per_joint(capsys, files):
    clean, _ = files
    fitted, _ = _run(capsys, ["fit", str(clean), "--json", *COMMANDS["fit"]])
    d, _ = _run(capsys, ["diagnose", str(clean), "--json", *COMMANDS["diagnose"]])
    assert d["rel_error_per_joint"] == pytest.approx(fitted["rel_error_per_joint"], rel=1e-9)
    s, _ = _run(capsys, ["discover", str(clean), "--json", *COMMANDS["discover"]])
    assert len(s["rel_error_per_joint"]) == 2
    # the whole is the joints' errors weighted by their torques: between the smallest and the largest
    assert all(e > 0 for e in s["rel_error_per_joint"])
    assert max(s["rel_error_per_joint"]) >= s["rel_error"] >= min(s["rel_error_per_joint"])
