"""`manus estimators` (docs/cli.md): its JSON, figures and errors, on the simulated arm and on both
EMPS files."""

import json

import numpy as np
import pytest

from manus import estimators
from manus.runs.cli import main

KEYS = {"name", "rms_error", "max_error", "moving", "still", "lag_ms", "noise_50hz"}


def test_manus_estimators_json_tune_and_figures(arm_recording, tmp_path, capsys):
    code = main(
        [
            "estimators",
            arm_recording.path,
            "--json",
            "--tune",
            "--out",
            str(tmp_path),
            "--only",
            "first_difference,filtered_first_difference",
        ]
    )
    out = json.loads(capsys.readouterr().out)  # nothing else on stdout
    assert code == 0 and out["truth"] is True and out["reference"] == "truth"
    rows = out["estimators"]
    assert [r["name"] for r in rows] == ["first_difference", "filtered_first_difference"]
    for r in rows:
        assert set(r) >= KEYS and {"rms_error", "max_error", "fraction"} <= set(r["moving"])
    assert "knob" not in rows[0]  # nothing to tune
    knob = rows[1]["knob"]
    assert knob["tuned"] and knob["criterion"] == "rms_error" and not knob["at_limit"]
    assert knob["name"] == "corner" and knob["value"] > 188.5  # less lag pays on this recording
    assert out["best"] == "filtered_first_difference"
    for path in out["figures"]["estimates"] + [out["figures"]["frequency_response"]]:
        assert (tmp_path / path.split("/")[-1]).stat().st_size > 10000


def test_manus_estimators_errors_are_one_line(arm_recording, tmp_path, capsys):
    assert main(["estimators", str(tmp_path / "none.csv")]) == 2
    assert "none.csv: no such file" in capsys.readouterr().err
    assert main(["estimators", arm_recording.path, "--only", "kalman_ca,psychic"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "unknown estimator 'psychic'" in err and "kalman_ca" in err


def test_manus_estimators_runs_on_both_emps_files(emps_dir, tmp_path, capsys):
    for name, grid in (("DATA_EMPS.mat", "grid"), ("DATA_EMPS_PULSES.mat", "noise")):
        code = main(
            [
                "estimators",
                str(emps_dir / name),
                "--json",
                "--no-figures",
                "--model",
                "rigid,viscous,coulomb,offset",
                "--param",
                "M1=95.1089",
                "--param",
                "b1=203.5034",
                "--param",
                "Fc1=20.3935",
                "--param",
                "off1=-3.1648",
            ]
        )
        out = json.loads(capsys.readouterr().out)
        assert code == 0 and out["truth"] is False and out["samples"] == 24841
        assert out["step"]["source"] == grid  # DATA_EMPS sits on a 5e-8 m grid, the PULSES file does not
        rows = {r["name"]: r for r in out["estimators"]}
        assert tuple(rows) == estimators.NAMES
        assert all(np.isfinite(r["rms_error"]) for r in rows.values())
        # against the offline reference (30 Hz): the thesis filter lags it by about 1/λ
        assert rows["filtered_first_difference"]["lag_ms"] == pytest.approx(5.3, abs=1.0)
        # the published model, in the model-based filter, follows the axis with little lag
        assert abs(rows["kalman_model"]["lag_ms"]) < 1.5
