"""System identification of thesis §3.5 on the simulated arm, and the Cartesian parameters of
§3.6 against finite differences, statics and the thesis's numbers at the workspace centre."""

import contextlib
import io
import json
import math

import numpy as np
import pytest

from manus.experiments import sysid
from manus.runs.cli import main

THESIS = {"a1": 0.349, "a2": 0.241, "a3": 0.246, "b1": 0.222, "b2": 0.181, "Fc1": 0.099, "Fc2": 0.139}


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert (
            main(
                [
                    "sysid",
                    "--displacement",
                    "0.3",
                    "--seconds",
                    "6",
                    "--out",
                    str(tmp_path_factory.mktemp("sysid")),
                    "--json",
                ]
            )
            == 0
        )
    return json.loads(out.getvalue())


def test_identified_parameters_within_5_percent_of_the_truth(result):
    p = result["params"]
    assert set(p) == {"a1", "b1", "Fc1", "a3", "b2", "Fc2", "H11*", "b*", "F*", "a2"}
    for name, v in p.items():
        assert abs(v["rel_error"]) < 0.05, (name, v)
    assert p["a2"]["truth"] == pytest.approx(0.241)  # the coupling, by eq. 3.12
    assert p["H11*"]["truth"] == pytest.approx(1.028, abs=1e-3)  # thesis eq. 3.13's H11*
    assert result["within_5pct"] and result["max_rel_error"] < 0.05


def test_fitted_models_replay_the_oscillations(result):
    for name, fit in result["fits"].items():
        assert fit["replay_rms"] < 2e-3, name  # rad, on a 0.3 rad oscillation
        assert fit["samples"] > 1000


def test_cartesian_parameters_at_the_centre_are_the_thesis(result):
    c = result["cartesian"]["centre"]
    assert c["radius"] == pytest.approx(0.508, abs=1e-3)  # 20 inches from the motor axis
    assert min(c["inertia_eig"]) == pytest.approx(1.0, rel=0.05)  # "m = 1 kg near the centre"
    assert c["damping"][0][0] == pytest.approx(1.6, abs=0.1)  # Fig. 4-28: 1.6 N·s/m in x
    for path in result["figures"].values():
        assert path.endswith(".png")


def test_kinematics():
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = np.array(sysid.CENTRE) + rng.uniform(-0.4, 0.4, 2)
        np.testing.assert_allclose(sysid.joint_angles(sysid.endpoint(q)), q, atol=1e-12)
        h = 1e-6
        fd = np.stack([(sysid.endpoint(q + h * e) - sysid.endpoint(q - h * e)) / (2 * h) for e in np.eye(2)], 1)
        np.testing.assert_allclose(sysid.jacobian(q), fd, atol=1e-8)
    with pytest.raises(ValueError, match="out of reach"):
        sysid.joint_angles([1.0, 0.5])


def test_endpoint_parameters_depend_on_the_radius_alone_and_friction_is_statics():
    q = np.array(sysid.CENTRE)
    a, b = sysid.cartesian(q, THESIS), sysid.cartesian(q + 0.3, THESIS)  # the arm turned as a whole
    for key in ("inertia", "damping"):
        np.testing.assert_allclose(np.linalg.eigvalsh(a[key]), np.linalg.eigvalsh(b[key]), rtol=1e-12)
    # Λ = J⁻ᵀ H J⁻¹: the kinetic energy is the same in both coordinates
    v = np.array([0.3, -0.2])
    J = sysid.jacobian(q)
    c = math.cos(q[1] - q[0])
    H = np.array([[THESIS["a1"], THESIS["a2"] * c], [THESIS["a2"] * c, THESIS["a3"]]])
    assert (J @ v) @ a["inertia"] @ (J @ v) == pytest.approx(v @ H @ v, rel=1e-12)
    # each corner of the parallelogram maps back to joint torques (±Fc1, ±Fc2): τ = Jᵀ F
    taus = a["friction"] @ J
    np.testing.assert_allclose(np.abs(taus), np.tile([THESIS["Fc1"], THESIS["Fc2"]], (4, 1)), rtol=1e-12)
