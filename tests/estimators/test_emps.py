"""The EMPS rig's real data (Janot, Gautier, Brunot 2019): its own velocity estimator rebuilds
the recorded controller output (`manus estimators` on both files: tests/runs/test_estimators_cmd.py)."""

import numpy as np
import pytest
from scipy.io import loadmat

from manus import estimators


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
