"""The EMPS rig's real data (Janot, Gautier, Brunot 2019): its own velocity estimator rebuilds
the recorded controller output, and `manus estimators` runs on both files."""

import json

import numpy as np
import pytest
from scipy.io import loadmat

from manus import estimators
from manus.runs.cli import main


def rig_output(m, estimate):
    """vir = kp·kv·(qg − qm) − kv·v̂ (the README's position-velocity loop) [V]."""
    kp, kv = float(m["kp"][0, 0]), float(m["kv"][0, 0])
    return kp * kv * (m["qg"].ravel() - m["qm"].ravel()) - kv * estimate


def test_the_rigs_estimator_rebuilds_its_controller_output(emps_dir):
    """v̂: the first difference of ½(qm(k) + qm(k−1)), i.e. (qm(k) − qm(k−2)) / 2T."""
    for name in ("DATA_EMPS.mat", "DATA_EMPS_PULSES.mat"):
        m = loadmat(emps_dir / name)
        qm = m["qm"].ravel()
        dt = float(np.median(np.diff(m["t"].ravel())))
        mean = np.concatenate([qm[:1], 0.5 * (qm[1:] + qm[:-1])])[:, None]
        v = np.asarray(estimators.run(estimators.make("first_difference", dt=dt), mean).qd)[:, 0]
        residual = (m["vir"].ravel() - rig_output(m, v))[10:]
        if "pulses_N" in m:  # the pulses were added to the output: take out their (fitted) share
            pulses = m["pulses_N"].ravel()[10:].astype(float)  # stored as uint8
            gain = np.dot(residual, pulses) / np.dot(pulses, pulses)
            assert gain == pytest.approx(1.01, abs=0.02)  # about 1 V of output per unit of pulses_N
            residual = residual - gain * pulses
        assert np.sqrt(np.mean(residual**2)) < 0.01, name  # 0.0037 V and 0.0047 V
        # and not the plain first difference of qm: that misses by ~14x more
        fd = np.asarray(estimators.run(estimators.make("first_difference", dt=dt), qm[:, None]).qd)[:, 0]
        if name == "DATA_EMPS.mat":
            assert np.sqrt(np.mean((m["vir"].ravel() - rig_output(m, fd))[10:] ** 2)) > 0.04


def test_manus_estimators_runs_on_both_emps_files(emps_dir, tmp_path, capsys):
    for name, grid in (("DATA_EMPS.mat", "grid"), ("DATA_EMPS_PULSES.mat", "noise")):
        code = main(["estimators", str(emps_dir / name), "--json", "--no-figures", "--model",
                     "rigid,viscous,coulomb,offset", "--param", "M1=95.1089", "--param", "b1=203.5034",
                     "--param", "Fc1=20.3935", "--param", "off1=-3.1648"])
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
