"""The literature estimators' own promises: Levant's differentiator is exact and, implicitly
discretized, does not chatter; FOAW averages quantization away when the motion is slow."""

import equinox as eqx
import numpy as np

from manus import estimators
from manus.estimators.sliding import K1, K2
from tests.estimators.conftest import DT, STEP

scan = eqx.filter_jit(estimators.run)
L = 50.0


def explicit_levant(f):
    """The same differentiator by explicit Euler, as usually written: it chatters."""
    z0, z1, out = f[0], 0.0, []
    for x in f:
        e = z0 - x
        z0, z1 = z0 + DT * (-K1 * np.sqrt(L) * np.sign(e) * np.sqrt(abs(e)) + z1), z1 - DT * K2 * L * np.sign(e)
        out.append(z1)
    return np.array(out)


def test_levant_is_exact_and_does_not_chatter():
    t = np.arange(3000) * DT
    f = 0.05 * np.sin(2 * np.pi * 1.5 * t)  # |f̈| ≤ 4.4 < L
    v = np.asarray(scan(estimators.make("levant", lipschitz=L), f[:, None]).qd)[:, 0]
    late = slice(1000, None)
    # exact up to the half-sample delay of a backward difference: z₁ = (f_k − f_{k−1}) / T on the sliding set
    np.testing.assert_allclose(v[late], np.diff(f, prepend=f[0])[late] / DT, atol=1e-9)
    chatter = lambda x: np.abs(np.diff(x[late], 2)).max()  # largest second difference of the output
    smooth = np.abs(np.diff(np.cos(2 * np.pi * 1.5 * t), 2)).max() * 0.05 * 2 * np.pi * 1.5
    assert chatter(v) < 1.1 * smooth  # as smooth as the true derivative
    assert chatter(explicit_levant(f)) > 100 * smooth  # the explicit version jumps by ~2 T k₂ L


def test_foaw_is_exact_at_rest_and_averages_slow_motion():
    t = np.arange(2000) * DT
    q = np.round((0.1 + 0.01 * t) / STEP) * STEP  # 0.01 rad/s: one encoder count every 4.8 ms
    q[:500] = q[500]  # at rest first
    fd = np.asarray(scan(estimators.make("first_difference"), q[:, None]).qd)[:, 0]
    foaw = np.asarray(scan(estimators.make("foaw"), q[:, None]).qd)[:, 0]
    assert np.all(foaw[:500] == 0.0)
    moving = slice(700, None)
    assert np.sqrt(np.mean((fd[moving] - 0.01) ** 2)) > 0.015  # spikes of one count (0.048 rad/s) per sample
    assert np.sqrt(np.mean((foaw[moving] - 0.01) ** 2)) < 0.002
