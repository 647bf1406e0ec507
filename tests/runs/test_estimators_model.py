"""`manus estimators` ranks the model-based estimators on a model identified from the recording
(issue 34 item 5): fitted on it by default, or a fit's JSON (`--model-from`), the report saying
which; refused fits and foreign JSONs. One simulated axis whose parameters are far from the
nominal model's defaults (M1 = 1, b1 = 1.5, Fc1 = 0.5)."""

import contextlib
import dataclasses
import io
import json

import numpy as np
import pytest

from manus.estimators import MODEL_BASED
from manus.estimators.compare import NOT_FITTED, compare
from manus.plants import recording
from manus.runs.analyses import FITTED
from manus.runs.cli import main

TRUTH = {"M1": 0.05, "b1": 0.2, "Fc1": 0.1}
AXIS = ["--structure", "axis", "--truth", "rigid,viscous,coulomb"]
ONLY = ["--only", ",".join(MODEL_BASED), "--no-figures"]


def _quiet(argv) -> str:
    """stdout of `manus ARGV`, which must succeed."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        assert main(argv) == 0
    return out.getvalue()


@pytest.fixture(scope="module")
def axis(tmp_path_factory):
    """(recording, the JSON of `manus fit REC --model rigid,viscous,coulomb --json`)."""
    folder = tmp_path_factory.mktemp("axis")
    rec = folder / "axis.csv"
    params = [x for k, v in TRUTH.items() for x in ("--param", f"{k}={v}")]
    _quiet(["simulate", *AXIS, "--joints", "1", *params, "--seconds", "6", "--out", str(rec), "--json"])
    fit = folder / "fit.json"
    fit.write_text(_quiet(["fit", str(rec), "--model", "rigid,viscous,coulomb", "--no-figures", "--json"]))
    return str(rec), fit


def _report(capsys, argv) -> dict:
    code = main(["estimators", *argv, "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out)


def _rms(report) -> dict:
    return {r["name"]: r["rms_error"] for r in report["estimators"]}


def _refused(capsys, argv, words: str) -> str:
    code = main(["estimators", *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1].startswith("manus estimators: "), err
    assert words in err[-1], err[-1]
    return err[-1]


def test_the_fitted_model_ranks_like_the_true_one_far_above_the_unfitted(axis, capsys):
    path, _ = axis
    fitted = _report(capsys, [path, *ONLY])
    m = fitted["model"]
    assert m["from"] == FITTED and m["spec"] == "rigid,viscous,coulomb" and m["rel_error"] < 0.02
    assert m["params"] == pytest.approx(TRUTH, rel=0.02)  # the fit finds the simulated axis
    true = _report(capsys, [path, *ONLY, *[x for k, v in TRUTH.items() for x in ("--param", f"{k}={v}")]])
    assert true["model"]["from"] == "--param" and true["model"]["set_by_hand"] == list(TRUTH)
    unfitted, _ = compare(recording.read(path), MODEL_BASED)  # what the command ranked them on before
    assert unfitted["model"]["from"] == NOT_FITTED and unfitted["model"]["params"]["M1"] == 1.0
    for name in MODEL_BASED:
        assert _rms(fitted)[name] == pytest.approx(_rms(true)[name], rel=0.02), name
        assert _rms(fitted)[name] < _rms(unfitted)[name] / 1.8, name  # measured: 2.0x and 2.4x


def test_a_fit_json_gives_what_the_fit_on_the_recording_gives(axis, capsys):
    path, fit = axis
    fitted = _report(capsys, [path, *ONLY])
    given = _report(capsys, [path, *ONLY, "--model-from", str(fit)])
    assert given["model"]["from"] == str(fit)
    assert given["model"]["spec"] == fitted["model"]["spec"]
    assert given["model"]["rel_error"] == fitted["model"]["rel_error"]
    assert given["model"]["params"] == pytest.approx(fitted["model"]["params"], rel=1e-12)
    assert _rms(given) == pytest.approx(_rms(fitted), rel=1e-9)
    # and the text says where the model came from
    assert main(["estimators", path, *ONLY, "--model-from", str(fit)]) == 0
    assert f"rigid,viscous,coulomb, from {fit}" in capsys.readouterr().out


def test_a_fit_of_another_joint_count_or_no_fit_at_all_is_refused_in_one_line(axis, tmp_path, capsys):
    path, fit = axis
    two = tmp_path / "two.csv"
    _quiet(["simulate", *AXIS, "--joints", "2", "--seconds", "3", "--out", str(two), "--json"])
    fit_of_two = tmp_path / "fit2.json"
    fit_of_two.write_text(_quiet(["fit", str(two), "--model", "rigid,viscous,coulomb", "--no-figures", "--json"]))
    _refused(capsys, [path, "--model-from", str(fit_of_two)], "a fit of 2 joint(s)")
    _refused(capsys, [str(two), "--model-from", str(fit)], "a fit of 1 joint(s)")

    _refused(capsys, [path, "--model-from", str(tmp_path / "none.json")], "no such file")
    (tmp_path / "broken.json").write_text('{"spec": "rigid"')
    _refused(capsys, [path, "--model-from", str(tmp_path / "broken.json")], "not valid JSON")
    (tmp_path / "report.json").write_text(json.dumps({"estimators": [], "best": "kalman_ca"}))
    _refused(capsys, [path, "--model-from", str(tmp_path / "report.json")], "not a fit's JSON")
    lacking = json.loads(fit.read_text())
    del lacking["params"]["Fc1"]
    (tmp_path / "lacking.json").write_text(json.dumps(lacking))
    _refused(capsys, [path, "--model-from", str(tmp_path / "lacking.json")], "lacks the parameter(s) Fc1")
    _refused(capsys, [path, "--model", "rigid", "--model-from", str(fit)], "give one")


def test_a_recording_that_cannot_identify_the_model_leaves_the_model_based_out(axis, tmp_path, capsys):
    rec = recording.read(axis[0])
    silent = recording.write(dataclasses.replace(rec, tau=np.zeros_like(rec.tau)), tmp_path / "silent.csv")
    r = _report(capsys, [str(silent), "--no-figures", "--only", "kalman_ca,kalman_model,luenberger_model"])
    assert [x["name"] for x in r["estimators"]] == ["kalman_ca"] and r["best"] == "kalman_ca"
    assert [x["name"] for x in r["left_out"]] == list(MODEL_BASED)
    assert all("cannot be identified" in x["reason"] and "torque is zero" in x["reason"] for x in r["left_out"])
    assert r["model"]["from"] == FITTED and "params" not in r["model"] and "torque is zero" in r["model"]["error"]
    assert main(["estimators", str(silent), "--no-figures", "--only", "kalman_ca,kalman_model"]) == 0
    assert "left out of the ranking: kalman_model: no model (" in capsys.readouterr().out


def test_a_fitted_parameter_within_two_std_of_its_bound_is_set_at_it_one_beyond_breaks_physics(axis):
    """Coulomb friction fitted on an axis without it comes out either side of zero: an estimator's
    model keeps every bound, so a value below it by less than two standard deviations is set at it
    (the report names it); beyond, the model breaks physics and the model-based are left out."""
    from manus.estimators.compare import EstimatorModel
    from manus.plants import Model
    from manus.runs.analyses import at_bounds

    rec = recording.read(axis[0])
    model = Model(rec.structure, "rigid,viscous,coulomb")
    fitted = {"M1": 0.05, "b1": 0.2, "Fc1": -1e-3}
    params, moved = at_bounds(model, fitted, {"M1": 1e-4, "b1": 1e-3, "Fc1": 1e-3})
    assert params == {"M1": 0.05, "b1": 0.2, "Fc1": 0.0} and moved == {"Fc1": -1e-3}
    params, moved = at_bounds(model, fitted, {"Fc1": 1e-4})
    assert params == fitted and not moved
    r, est = compare(rec, ("kalman_ca", "kalman_model"), model=EstimatorModel(FITTED, model.spec, model, params))
    assert [x["name"] for x in r["estimators"]] == ["kalman_ca"] and "kalman_model" not in est
    assert r["left_out"][0]["name"] == "kalman_model" and "Fc1" in r["left_out"][0]["reason"]
    assert "break physics" in r["model"]["error"]
