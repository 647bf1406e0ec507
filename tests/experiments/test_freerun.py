"""The free run of a fitted model (`manus.experiments.freerun`) open loop: IV's windows from the
measured state (closed loop through the recorded controller: tests/runs/test_fit_cmds.py)."""

import numpy as np
import pytest

from manus.adaptive import fit
from manus.adaptive.identify import instruments
from manus.experiments.freerun import free_run
from tests.adaptive import hidden


@pytest.fixture(scope="module")
def nominal():
    """The MANUS-2 arm under impedance control, fitted with its true effects."""
    return fit(hidden.recording(()), "rigid,viscous,coulomb")


def test_open_loop_runs_the_windows_from_the_measured_state(nominal):
    """Asked open loop, the recorded torque drives 0.5 s windows, each starting exactly at the
    measured (filtered) state; the true model's windows follow the recorded positions to within
    a small share of their swing, for the two joints."""
    run = free_run(nominal, open_loop=True)
    assert run.mode == "open loop" and "windows of 0.5 s" in run.how
    W = instruments.window_size(nominal.data)
    assert W == 500
    np.testing.assert_array_equal(run.q_sim[::W], nominal.data.q[::W])
    assert run.fit_q.min() > 99.0, run.fit_q
    assert run.fit_tracking is None and run.report()["mode"] == "open loop"
