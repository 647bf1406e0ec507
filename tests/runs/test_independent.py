"""The independent simulator (`manus.experiments.independent`, written from the equations, not from
`manus.plants`) against manus's own model, and diagnose on its recordings: the first recordings a
user's other simulator would give (friction regularized, so a held joint creeps)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.adaptive import diagnose, fit, prepare
from manus.experiments import independent
from manus.plants.effects import Model
from manus.plants.structures import Manus2


def test_independent_arm_dynamics_match_manus_model():
    """Lagrange's equations written out in `independent` and manus's Manus2 model (thesis eqs.
    3.2–3.4) give the same torque for the same motion: the two are independent references of
    each other. Speeds well above the friction's regularization (tanh = sgn there)."""
    rng = np.random.default_rng(0)
    cfg = independent.ARM
    zero = np.zeros(2)
    p = dict(
        b=np.array(cfg["b"]),
        fc=np.array(cfg["fc"]),
        dfs=zero,
        db=zero,
        off=zero,
        k=zero,
        q0=zero,
        gc=zero,
        gs=zero,
        ca=zero,
        cb=zero,
        order=zero,
    )
    model = Model(Manus2(), "rigid,viscous,coulomb")
    params = {
        "a1": independent.A1,
        "a2": independent.A2,
        "a3": independent.A3,
        "b1": cfg["b"][0],
        "b2": cfg["b"][1],
        "Fc1": cfg["fc"][0],
        "Fc2": cfg["fc"][1],
    }
    with jax.enable_x64(True):
        for _ in range(20):
            q = rng.uniform(-3, 3, 2)
            v = rng.uniform(0.2, 2.0, 2) * rng.choice([-1, 1], 2)
            tau = rng.uniform(-2, 2, 2)
            a = np.asarray(
                independent._acceleration(
                    True,
                    cfg,
                    {k: jnp.asarray(x) for k, x in p.items()},
                    jnp.asarray(q),
                    jnp.asarray(v),
                    jnp.asarray(tau),
                )
            )
            back = np.asarray(model.torque(jnp.asarray(q), jnp.asarray(v), jnp.asarray(a), params))
            np.testing.assert_allclose(back, tau, rtol=0, atol=1e-9)


def test_independent_null_recording_fits_its_truth():
    """manus fit on an independent recording (read back from its CSV file) recovers the true
    inertias and friction of the arm: 1 kHz, multi-sine, torque exact."""
    c = independent.case(1, None, structure="arm", rate=1000, excitation="multisine", torque="exact", hold="stated")
    f = fit(c.rec, c.start)
    truth = {
        "a1": independent.A1,
        "a2": independent.A2,
        "a3": independent.A3,
        "b1": independent.ARM["b"][0],
        "b2": independent.ARM["b"][1],
        "Fc1": independent.ARM["fc"][0],
        "Fc2": independent.ARM["fc"][1],
    }
    for k, v in truth.items():
        assert f.params[k] == pytest.approx(v, rel=0.05 if k.startswith("a") else 0.15), k
    assert f.rel_error < 0.05


def test_independent_creeping_holds_are_left_out():
    """A joint held against regularized friction creeps (speeds of order ε, above the encoder's
    standstill threshold) instead of sticking: its friction there is anything between ±Fc. The
    holds are left out like a standstill (`fit.CREEP`): the axis at 200 Hz reaching, torque exact,
    with nothing hidden. Nothing is proposed but the engine's own friction law where the data
    resolve it: Fc tanh(q̇/ε), `smooth` at a width within a factor 2 of ε (1e-4 m/s)."""
    c = independent.case(1634520124, None)
    assert c.condition["structure"] == "axis" and c.condition["excitation"] == "reaching"
    data = prepare(c.rec)
    assert data.standstill > 0.4
    d = diagnose(data, c.start)
    if d.verdict is not None:
        assert d.verdict.effect == "smooth", d.verdict.spec
        assert 0.5 < d.verdict.detail["width"] / independent.AXIS["eps"] < 2, d.verdict.spec


def test_independent_hidden_offset_named():
    """An offset hidden at 5 % of the torque on the independent arm, read back from its file,
    is named on its joint."""
    c = independent.case(7, "offset", structure="arm", rate=1000, excitation="multisine", torque="exact")
    d = diagnose(c.rec, c.start)
    assert d.verdict is not None and d.verdict.effect == "offset"
    if c.joint is not None:
        assert d.verdict.joint == c.joint


def test_independent_bench_path(calibrate_args):
    """`manus bench diagnose --calibrate --simulator independent`: its recordings go through the
    same judging as the calibration's, its effects are its own (no compliance: refused by name)."""
    from manus.plants.errors import ManusError
    from manus.runs.bench import diagnose as bench

    args = calibrate_args(
        recordings=1, effects="viscous", seed=4, alpha=None, blocks=None, jobs=1, simulator="independent"
    )
    r = bench.calibrate(args)
    assert [x["hidden"] for x in r["results"]] == [None, "viscous"] and r["simulator"] == "independent"
    assert all(x["condition"]["simulator"] == "independent" for x in r["results"])
    assert r["crashes"] == {} and r["rates"] == list(independent.RATES)
    assert "independent simulator" in bench.render_calibration(r)
    with pytest.raises(ManusError, match="the independent simulator hides"):
        bench.calibrate(calibrate_args(**{**vars(args), "effects": "compliance"}))
