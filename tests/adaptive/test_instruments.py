"""IDIM-IV's simulation (`manus.adaptive.identify.instruments`): windows restarted from the measured
state against one continuous run of the simulator, the sub-steps chosen from the period, and the
iterations' stop."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.adaptive import Columns, prepare
from manus.adaptive.identify import instruments
from manus.adaptive.identify.fit import model_from
from manus.adaptive.identify.result import fit_rows
from manus.adaptive.identify.search import search_all
from manus.plants import Model, Simulator
from manus.plants.recording import Recording
from manus.plants.structures import Manus2
from tests.adaptive import hidden

RATE = 1000.0


def continuous(model: Model, params: dict, tau: np.ndarray, q0) -> tuple[np.ndarray, np.ndarray]:
    """(q, q̇) before each command of one run over the whole command, 10 sub-steps per period."""
    sim = Simulator(model, params, rate_hz=RATE, substeps=10, actuator=None, encoder=None, q0=q0)
    state, _ = sim.reset()

    def tick(st, u):
        q, qd = sim.truth(st)
        return sim.step(st, u)[0], (q, qd)

    q, qd = jax.lax.scan(tick, state, jnp.asarray(tau))[1]
    return np.asarray(q), np.asarray(qd)


def test_sub_steps_follow_the_period():
    assert [instruments.substeps(1 / r) for r in (100, 200, 1000, 2000, 5000)] == [20, 10, 2, 1, 1]


def test_windows_follow_a_continuous_run_from_their_first_sample():
    """Open loop, a 3 ms delay: restarted every `WINDOW_S` from the state of one continuous run
    (the reference, 10 sub-steps per period), with the commands sent before each window in its
    delay line, the windows (2 sub-steps per period) follow that run: 0.03 µrad over a window's
    first 20 ms, ~0.1 mrad by its end (the sub-steps' error, 0.05 % of the swing), where a delay
    line started empty would miss 3 ms of torque at each start (~3 mrad by the window's end). The
    first window is left out: the run started with an empty delay line, the windows with the
    first command in it."""
    model = Model(Manus2(), "rigid,viscous,coulomb,delay:3ms")
    params = model.defaults()
    t = np.arange(0, 2.0, 1 / RATE)
    tau = np.stack([0.8 * np.sin(2 * np.pi * 1.3 * t), 0.5 * np.sin(2 * np.pi * 0.9 * t + 1)], 1)
    q, qd = continuous(model, params, tau, (0.464, 2.409))
    rec = Recording(t, q, tau, qd, {"sample_rate_hz": str(RATE), "command_hold": "zoh", "structure": "manus2"})
    data = dataclasses.replace(prepare(rec), q=q, qd=qd)  # restarts from the true state
    run = instruments.windows(data, model, params)
    assert run is not None
    W = instruments.window_size(data)
    err = np.abs(run[0] - q).max(axis=1).reshape(-1, W)[1:]  # (window, sample)
    assert W == 500 and err[:, :20].max() < 1e-6 and err.max() < 3e-4, (err[:, :20].max(), err.max())


@pytest.fixture(scope="module")
def nominal():
    """The MANUS-2 arm under impedance control, least squares of its nominal model."""
    data = prepare(hidden.recording(()))
    cols = Columns(data)
    model, search = search_all(data, cols, model_from("rigid,viscous,coulomb", data.rec.structure)[0], set())
    return data, cols, fit_rows(data, cols, model, search)


def test_iterations_stop_once_the_parameters_stay(nominal, monkeypatch):
    """Where the instruments simulated from θ give θ back within 0.1 std, IV stops: here after
    two simulations, within 0.1 std of the three rounds run regardless."""
    data, cols, ls = nominal
    calls = []
    simulate = instruments.simulate
    monkeypatch.setattr(instruments, "simulate", lambda *a: calls.append(1) or simulate(*a))
    stopped = instruments.iv_fit(data, cols, ls, "iv")
    assert len(calls) == 2
    monkeypatch.setattr(instruments, "CONVERGED", 0.0)
    full = instruments.iv_fit(data, cols, ls, "iv")
    assert len(calls) == 2 + instruments.ITERATIONS
    assert np.all(np.abs(stopped.theta - full.theta) <= 0.1 * full.std)
    truth = hidden.truth_params(())
    for k in ("b1", "b2", "Fc1", "Fc2"):
        assert stopped.params[k] == pytest.approx(truth[k], rel=0.05), k


def test_auto_stops_once_least_squares_is_kept_whatever_iv_gives(nominal, monkeypatch):
    """Under `auto`, IV within `SETTLED` combined std of LS (which breaks no rule) keeps LS after
    one simulation: the fit the iterations run to convergence choose, the same numbers."""
    data, cols, ls = nominal
    calls = []
    simulate = instruments.simulate
    monkeypatch.setattr(instruments, "simulate", lambda *a: calls.append(1) or simulate(*a))
    quick = instruments.iv_fit(data, cols, ls, "auto")
    assert len(calls) == 1 and quick.method == "ls", quick.why
    monkeypatch.setattr(instruments, "SETTLED", 0.0)
    slow = instruments.iv_fit(data, cols, ls, "auto")
    assert len(calls) > 2 and slow.method == "ls", slow.why
    np.testing.assert_array_equal(quick.theta, slow.theta)
    assert quick.why.startswith("LS and IV agree within") and slow.why.startswith("LS and IV agree within")
