"""The Python API (`manus.runs.api`): each result's JSON is its command's, its figures are
Figures and files only when asked, and manus computes in float64 in a process that only imported
it."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from matplotlib.figure import Figure

import manus
from manus.plants.errors import ManusError
from manus.runs import api
from manus.runs.cli import main
from tests.adaptive import hidden

MODEL = "rigid,viscous,coulomb"


@pytest.fixture(scope="module")
def rec():
    return hidden.recording(("offset",), seconds=10.0)


@pytest.fixture(scope="module")
def csv(rec, tmp_path_factory):
    from manus.plants.recording import write

    return write(rec, tmp_path_factory.mktemp("api") / "arm.csv")


def test_importing_manus_alone_computes_in_float64():
    code = "import manus, jax.numpy as jnp; print(jnp.ones(1).dtype, jnp.asarray(0.1).dtype)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.split() == ["float64", "float64"]


def test_discover_is_the_command_s_json(csv, capsys):
    d = manus.discover(csv, MODEL)
    assert "offset" in d.model.split(",")
    assert main(["discover", str(csv), "--model", MODEL, "--json", "--no-figures"]) == 0
    assert json.loads(d.to_json()) == json.loads(capsys.readouterr().out)
    assert d.kinds()[0] == "waterfall" and "step1" in d.kinds()
    assert isinstance(d.figure("waterfall"), Figure)
    assert "<table>" in d._repr_html_() and "offset" in str(d)


def test_diagnosis_figures_and_files_only_when_asked(csv, tmp_path):
    d = manus.diagnose(csv, MODEL)
    assert d.verdict == "offset" and d.kinds()[0] == "resid" and "offset" in d.kinds()
    assert isinstance(d.figure("offset"), Figure)
    assert not list(tmp_path.iterdir())  # drawing wrote nothing
    with pytest.raises(ManusError, match="no figure 'nope'; the figures are resid"):
        d.figure("nope")
    fit = manus.fit(csv, MODEL + ",offset")
    written = fit.save_figures(tmp_path)
    assert list(written) == ["compare"] and (tmp_path / "fit_compare.png").stat().st_size > 10_000
    assert fit.parameters["off1"] == pytest.approx(hidden.truth_params(("offset",))["off1"], rel=0.02)
    assert fit.report["params"]["off1"]["unit"] == "N·m"


def test_estimators_on_a_fitted_model(rec):
    r = manus.estimators(rec, only=["kalman_ca", "kalman_model"])
    assert isinstance(r, api.EstimatorsResult)
    assert r.report["model"]["from"] == "fitted on this recording"
    assert {e["name"] for e in r.report["estimators"]} == {"kalman_ca", "kalman_model"}
    assert r.kinds() == ["estimates1", "estimates2", "response"]
    assert isinstance(r.figure("response"), Figure)
    assert callable(manus.estimators) and manus.estimators.make is not None  # the package, callable


def test_a_recording_is_not_read_again(rec):
    assert manus.read(rec) is rec
    with pytest.raises(ManusError, match="read already"):
        manus.read(rec, columns="t=t")
