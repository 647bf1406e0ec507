"""The Type 1 analysis against the thesis (eq. 4.1 poles), closed forms, python-control's own
margins, and the project's simulator (the exactly sampled plant with a fractional delay)."""

import control
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

from manus.experiments.stability.linear import SPRINGS, LinearAxis
from manus.experiments.stability.steptest import StepTest

M, B, LAM = 1.0, 1.5, 188.5


def test_eq41_poles_are_the_thesis():
    poles = np.sort_complex(control.poles(LinearAxis().closed_loop(100.0, 2.0)))
    # the polynomial of eq. 4.1 written out, solved by numpy
    ref = np.sort_complex(np.roots([M, M * LAM + B, B * LAM + 2.0 * LAM + 100.0, 100.0 * LAM]))
    np.testing.assert_allclose(poles, ref, rtol=1e-9)
    assert poles[0].real == pytest.approx(-186.5, abs=0.05)  # thesis §3.7: −186.5, −1.7 ± 9.9i
    assert abs(poles[1].real + 1.7) < 0.1 and abs(abs(poles[1].imag) - 9.9) < 0.05


def test_eq42_adds_the_spring_to_the_denominator():
    k, b_c, ke = 300.0, 4.0, 3826.0
    tf = LinearAxis(spring=ke).closed_loop(k, b_c)
    ref = np.roots([M, M * LAM + B, B * LAM + b_c * LAM + k + ke, (k + ke) * LAM])
    np.testing.assert_allclose(np.sort_complex(control.poles(tf)), np.sort_complex(ref), rtol=1e-9)


def test_k_max_without_damping_is_the_closed_form():
    """b_c = 0: L = e^{−jωτ}/(jω(jωm + b)); the phase crossover solves ωτ + atan(ωm/b) = π/2 and
    k_max = ω √(m²ω² + b²)."""
    tau = 1e-3
    w: float = scipy.optimize.brentq(lambda w: w * tau + np.arctan(w * M / B) - np.pi / 2, 1.0, 1e4, xtol=1e-14)  # pyright: ignore[reportAssignmentType] (a float without full_output)
    assert LinearAxis().k_max(0.0) == pytest.approx(w * np.hypot(M * w, B), rel=1e-6)


@pytest.mark.parametrize("b_c", [2.0, 10.0, 30.0])
def test_k_max_matches_python_control_margins(b_c):
    """python-control's gain margin of the same loop as a transfer function with a Padé delay."""
    s: control.TransferFunction = control.tf("s")  # pyright: ignore[reportAssignmentType] (python-control is untyped)
    delay: control.TransferFunction = control.tf(*control.pade(1e-3, 8))  # pyright: ignore[reportAssignmentType]
    plant = 1 / (M * s**2 + B * s)  # pyright: ignore[reportOperatorIssue] (TransferFunction.__pow__ is untyped)
    loop = control.feedback(delay * plant, b_c * LAM * s / (s + LAM))
    gm = np.atleast_1d(control.stability_margins(loop, returnall=True)[0])
    assert LinearAxis().k_max(b_c) == pytest.approx(gm[gm > 0].min(), rel=1e-4)


@pytest.mark.parametrize("rate", [None, 1000.0, 100.0])
def test_k_max_is_where_the_closed_loop_poles_cross(rate):
    for spring in (0.0, SPRINGS[2]):
        lin = LinearAxis(spring=spring)
        for b_c in (0.0, 8.0):
            k = lin.k_max(b_c, rate)
            assert lin.stable(0.995 * k, b_c, rate) and not lin.stable(1.005 * k, b_c, rate)


def test_type1_threshold_rises_with_damping_and_falls_with_sampling():
    lin = LinearAxis()
    cont = [lin.k_max(b) for b in (0.0, 5.0, 20.0)]
    fast, slow = lin.k_max(5.0, 1000.0), lin.k_max(5.0, 100.0)
    assert cont[0] < cont[1] < cont[2]  # the positive slope of the Type 1 edge
    assert slow < fast < cont[1]  # sampling adds delay: lower thresholds
    assert np.isnan(lin.k_max(-2.0))  # below −b no stiffness helps


def test_sampled_plant_is_the_simulator_with_a_fractional_delay_and_a_spring():
    """The exactly sampled model (zero-order hold, 1 ms delay at 100 Hz: a tenth of a period,
    a 1050 N/m environment) against the project's sub-stepped simulator with the step test's
    `Spring` effect, driven by the same commands."""
    test = StepTest(rate_hz=100.0, compliance=False, quantum=0.0, spring=1050.0, physics_hz=20000.0)
    sim = test.plant()
    u = np.random.default_rng(1).normal(0, 1.0, 150)
    state, _ = sim.reset(q0=jnp.zeros(1))
    run = eqx.filter_jit(lambda st, us: jax.lax.scan(lambda s, x: (sim.step(s, x)[0], s.q[0]), st, us)[1])
    q = np.asarray(run(state, jnp.asarray(u)[:, None]))
    resp = control.forced_response(test.linear().sampled(test.rate_hz), T=np.arange(u.size) / test.rate_hz, U=u)
    assert np.max(np.abs(q)) > 1e-4  # it moved
    # the sub-stepped integration is second order: 2e-5 relative here; a delay off by one
    # sub-step (50 µs) would be 2e-3
    np.testing.assert_allclose(q, resp.outputs, rtol=0, atol=1e-4 * np.max(np.abs(q)))


def test_negative_damping_limit_is_about_minus_b():
    lin = LinearAxis()
    for rate in (None, 1000.0):
        edge = lin.b_c_min(10.0, rate)
        assert -1.5 < edge < -1.45  # the thesis's −1.5, less the delay's negative damping k·τ
        assert lin.stable(10.0, edge + 0.005, rate) and not lin.stable(10.0, edge - 0.005, rate)
