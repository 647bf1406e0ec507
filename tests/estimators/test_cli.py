"""`manus estimators` (docs/cli.md) and the registry's errors."""

import json

import jax.numpy as jnp
import numpy as np
import pytest

from manus import estimators
from manus.plants.errors import ManusError
from manus.runs.cli import main

KEYS = {"name", "rms_error", "max_error", "moving", "still", "lag_ms", "noise_50hz"}


def test_manus_estimators_json_tune_and_figures(arm_recording, tmp_path, capsys):
    code = main(["estimators", arm_recording.path, "--json", "--tune", "--out", str(tmp_path),
                 "--only", "first_difference,filtered_first_difference"])
    out = json.loads(capsys.readouterr().out)  # nothing else on stdout
    assert code == 0 and out["truth"] is True and out["reference"] == "truth"
    rows = out["estimators"]
    assert [r["name"] for r in rows] == ["first_difference", "filtered_first_difference"]
    for r in rows:
        assert KEYS <= set(r) and {"rms_error", "max_error", "fraction"} <= set(r["moving"])
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


def test_make_refuses_what_it_does_not_know():
    with pytest.raises(ManusError, match="unknown estimator 'kalmann'.*first_difference.*foaw"):
        estimators.make("kalmann")
    with pytest.raises(ManusError, match="kalman_ca has no setting bandwidth.*takes q, steady"):
        estimators.make("kalman_ca", bandwidth=3.0)
    with pytest.raises(ManusError, match="must be positive"):
        estimators.make("levant", lipschitz=-1.0)
    with pytest.raises(ManusError, match="unknown parameter.*a9"):
        estimators.make("kalman_model", params={"a9": 1.0})
    with pytest.raises(ManusError, match="parameters break physics: a1 = -1"):
        estimators.make("luenberger_model", params={"a1": -1.0})
    est = estimators.make("luenberger_model", n_joints=1, structure="axis")
    with pytest.raises(ManusError, match="shape"):
        est.with_params(est.init(jnp.zeros(1)), np.ones(7))
    with pytest.raises(ManusError, match="no model"):
        estimators.make("luenberger").with_params(None, {})
    assert set(estimators.KNOBS) == set(estimators.NAMES) - {"first_difference"}
    assert len(estimators.NAMES) == len(set(estimators.NAMES)) >= 9
