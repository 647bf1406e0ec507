"""`manus fit`, `diagnose`, `discover`, `demo` and `bench diagnose`: the command-line contract
(docs/cli.md), the figures and the report, the loop finding a hidden effect, and bad input.

One simulated recording is shared: the arm under impedance control for 20 s with 39/rev cogging
hidden from the thesis's nominal model (rigid, viscous, Coulomb)."""

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from manus.plants.effects import VOCABULARY
from manus.runs.cli import main

TRUTH = "rigid,viscous,coulomb,cogging:39"
NOMINAL = "rigid,viscous,coulomb"


@pytest.fixture(scope="module")
def hidden_cogging(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("rec") / "hidden.csv"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["simulate", "--truth", TRUTH, "--seconds", "20", "--out", str(path), "--json"]) == 0
    return str(path)


def _json(capsys, argv) -> dict:
    code = main(argv + ["--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    lines = [line for line in captured.out.splitlines() if line.strip()]
    assert len(lines) == 1, "--json prints exactly one line on stdout"
    return json.loads(lines[0])


def _fails(capsys, argv, words: str) -> str:
    code = main(argv)
    captured = capsys.readouterr()
    assert code != 0
    assert captured.out == ""
    assert "Traceback" not in captured.err, captured.err
    # progress notes may come first; the error is one line, the last
    errors = [line for line in captured.err.strip().splitlines() if line.startswith(f"manus {argv[0]}:")]
    assert len(errors) == 1 and captured.err.strip().endswith(errors[0]), captured.err
    assert words in errors[0], errors[0]
    return errors[0]


def test_fit_reports_every_parameter_with_std_and_the_compare_figure(capsys, hidden_cogging, tmp_path):
    r = _json(capsys, ["fit", hidden_cogging, "--model", f"{NOMINAL},cogging", "--out", str(tmp_path)])
    assert set(r) >= {"model", "params", "rel_error", "samples"}
    assert r["model"] == ["rigid", "viscous", "coulomb", "cogging"]
    assert set(r["params"]) == {"a1", "a2", "a3", "b1", "b2", "Fc1", "Fc2", "A1", "A2", "B1", "B2"}
    assert all(set(p) == {"value", "std", "unit"} and p["std"] > 0 for p in r["params"].values())
    assert r["nonlinear"]["order"] == 39  # the cogging order, searched
    # the thesis's inertia parameters (manus.plants.structures defaults) within 2 %
    for k, truth in {"a1": 0.349, "a2": 0.241, "a3": 0.246}.items():
        assert abs(r["params"][k]["value"] / truth - 1) < 0.02, (k, r["params"][k])
    assert r["rel_error"] < 0.015 and r["samples"] > 500
    # the free run follows the recorded reference through the recorded impedance controller
    assert r["free_run"]["mode"] == "closed loop"
    assert min(r["free_run"]["tracking_error_fit_percent"]) > 90
    assert min(r["fit_percent"]["torque"]) > 98
    assert Path(r["figures"]["compare"]).stat().st_size > 20_000


def test_fit_text_output_is_a_parameter_table(capsys, hidden_cogging, tmp_path):
    assert main(["fit", hidden_cogging, "--model", NOMINAL, "--no-figures"]) == 0
    out = capsys.readouterr().out
    assert "rel_error" in out and "Fc2" in out and "std" in out


def test_diagnose_names_the_hidden_effect_and_draws_its_evidence(capsys, hidden_cogging, tmp_path):
    r = _json(capsys, ["diagnose", hidden_cogging, "--model", NOMINAL, "--out", str(tmp_path)])
    assert set(r) >= {"model", "rel_error", "candidates", "verdict"}
    assert r["verdict"] == "cogging"
    best = r["candidates"][0]
    assert best["effect"] == "cogging" and best["significant"] and best["error_reduction"] > 0.5
    assert best["detail"]["order"] == 39
    assert {c["effect"] for c in r["candidates"]} >= {"stribeck", "asymmetry", "offset", "gravity", "delay"}
    assert all({"effect", "joint", "error_reduction", "significant", "detail"} <= set(c) for c in r["candidates"])
    figs = r["figures"]
    assert Path(figs["resid"]).stat().st_size > 50_000
    assert set(figs["evidence"]) >= {"cogging", "delay", "offset"}
    assert all(Path(p).exists() for p in figs["evidence"].values())


def test_discover_finds_the_hidden_effect_and_the_error_falls(capsys, hidden_cogging, tmp_path):
    r = _json(capsys, ["discover", hidden_cogging, "--model", NOMINAL, "--no-figures"])  # figures: the demo test
    assert [s["effect"] for s in r["steps"]] == ["cogging"]
    step = r["steps"][0]
    assert step["params"]["order"] == 39 and set(step["params"]) >= {"A1", "A2", "B1", "B2"}
    assert step["rel_error"] < 0.5 * r["start"]["rel_error"]  # most of the error was the cogging
    assert r["stopped"] == "nothing significant missing"
    assert "report" not in r


def test_demo_part_a_discovers_the_hidden_effects_and_says_when_emps_is_missing(capsys, tmp_path):
    r = _json(capsys, ["demo", "--seconds", "20", "--emps", str(tmp_path / "nowhere.mat"), "--out", str(tmp_path)])
    steps = r["simulated"]["discovery"]["steps"]
    assert [s["effect"] for s in steps] == ["cogging", "delay"]  # the 39/rev cogging and the amplifier's 1 ms
    assert abs(steps[1]["params"]["delay_ms"] - 1.0) < 0.2
    assert steps[-1]["rel_error"] < 0.25 * r["simulated"]["discovery"]["start"]["rel_error"]
    assert "nowhere.mat" in r["emps"]["skipped"]
    report = Path(r["report"])
    text = report.read_text()
    links = [line.split("](")[1].rstrip(")") for line in text.splitlines() if line.startswith("![")]
    assert len(links) >= 5  # waterfall, the two steps' evidence, the final residual, compare
    assert all((report.parent / link).exists() for link in links)
    assert "a_waterfall.png" in text and "a_step1_cogging.png" in text and "a_step2_delay.png" in text


def test_bad_input_is_one_line_and_a_non_zero_exit(capsys, hidden_cogging, tmp_path):
    _fails(capsys, ["fit", hidden_cogging, "--model", "rigid,frobnicate"], "unknown effect 'frobnicate'")
    _fails(capsys, ["fit", str(tmp_path / "missing.csv"), "--model", NOMINAL], "no such file")
    every = ",".join(VOCABULARY)
    _fails(capsys, ["diagnose", hidden_cogging, "--model", every], "every effect")
    _fails(capsys, ["discover", hidden_cogging, "--model", every], "every effect")
    # too short: 0.1 s
    t = np.arange(100) * 1e-3
    short = tmp_path / "short.csv"
    np.savetxt(
        short,
        np.c_[t, 0.4 + 0.1 * t, 2.4 + 0 * t, np.sin(t), np.cos(t)],
        delimiter=",",
        header="t,q1,q2,tau1,tau2",
        comments="# sample_rate_hz: 1000\n",
    )
    _fails(capsys, ["fit", str(short), "--model", NOMINAL], "too short")
    # motionless: 5 s at rest, torque noise only
    t = np.arange(5000) * 1e-3
    still = tmp_path / "still.csv"
    noise = np.random.default_rng(0).normal(0, 0.1, (t.size, 2))
    np.savetxt(
        still,
        np.c_[t, 0.4 + 0 * t, 2.4 + 0 * t, noise],
        delimiter=",",
        header="t,q1,q2,tau1,tau2",
        comments="# sample_rate_hz: 1000\n# counts_per_rev: 131072\n",
    )
    line = _fails(capsys, ["diagnose", str(still), "--model", NOMINAL], "")
    assert "motion" in line or "too short" in line
    _fails(capsys, ["demo", "--seconds", "1"], "at least 5 s")


def test_bench_diagnose_times_diagnose_beside_a_scipy_fit_of_the_same_model(capsys):
    r = _json(capsys, ["bench", "diagnose", "--seconds", "8", "--repeats", "0"])
    f = r["figures"]
    assert f["diagnose_s"] > 0 and f["scipy_least_squares_s"] > 0
    assert r["candidates"] >= 6
    # the plain scipy fit of the same model lands on the same parameters
    assert r["scipy_vs_fit_max_rel_diff"] < 1e-3
    assert abs(r["rel_error"]["scipy"] - r["rel_error"]["fit"]) < 1e-4


def test_fit_on_emps_gives_the_published_model(capsys, emps_dir):
    r = _json(
        capsys,
        [
            "fit",
            str(emps_dir / "DATA_EMPS.mat"),
            "--model",
            "rigid,viscous,coulomb,offset",
            "--no-figures",
            "--cutoff",
            "100",
        ],
    )  # the reference's band
    published = {"M1": 95.1089, "b1": 203.5034, "Fc1": 20.3935, "off1": -3.1648}  # ../shared/data/emps/README.md
    for k, v in published.items():
        assert abs(r["params"][k]["value"] / v - 1) < 0.01, (k, r["params"][k])
    assert abs(r["rel_error"] - 0.0408) < 0.005
