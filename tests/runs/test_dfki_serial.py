"""The real DFKI double pendulum in its own relative coordinates, from a URDF written from its
published geometry (examples/dfki_double_pendulum): against MANUS-2's absolute-angle structure on
the same samples, and against DFKI's published model_2.0 (NOTES.md of the data)."""

import importlib.util
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import SHARED

DFKI = SHARED / "data" / "real" / "dfki_double_pendulum"
EXAMPLE = pathlib.Path(__file__).resolve().parents[2] / "examples" / "dfki_double_pendulum"


def _module(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLE / f"{name}.py")
    assert spec is not None and spec.loader is not None  # a .py file has a spec with a loader
    sys.path.insert(0, str(EXAMPLE))
    try:
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(EXAMPLE))
    return mod


@pytest.fixture(scope="module")
def comparison(files):
    return _module("compare").compare(files)


def test_relative_coordinates_explain_more_than_absolute_angles(comparison):
    """The elbow motor rides on link 1: its friction acts on the relative rate, which the URDF
    chain expresses and MANUS-2's per-joint friction on absolute rates cannot. On the same
    samples, measured on either set of torques, the chain's error is below MANUS-2's on every
    recording, and by a third or more on average."""
    for r in comparison["recordings"]:
        for metric in ("absolute_torques", "motor_torques"):
            e = r["same_samples"][metric]
            assert e["urdf"] < e["manus2"], (r["file"], metric, e)
    ratio = comparison["error_ratio_manus2_over_urdf"]
    assert ratio["absolute_torques"] > 1.3 and ratio["motor_torques"] > 1.25, ratio


def test_rigid_base_parameters_match_dfki_published(comparison):
    """The identifiable rigid combinations (median over the six recordings, manus fit's defaults:
    IV where LS is biased) against DFKI's model_2.0 written into the URDF: the first moments
    (gravity: m1 r1 + m2 l1, m2 r2) and the inertias about the joints within 10 %. The elbow's
    armature comes out larger (the rotor's gear coupling gr·Ir in M12 has no place in a URDF and
    lands there) and Coulomb friction above DFKI's (identified from the driver-reported torques
    with b held fixed): reported, not asserted."""
    pub, med = comparison["published"], comparison["median"]
    for k in ("mz1R", "Iyy1R", "mz2", "Iyy2"):
        assert med[k] == pytest.approx(pub[k], rel=0.10), (k, med[k], pub[k])
    assert abs(med["mx1"]) < 0.05 * abs(pub["mz1R"]) and abs(med["mx2"]) < 0.05 * abs(pub["mz2"])
    assert med["Fc1"] > 0 and med["Fc2"] > 0 and med["Ia2"] > 0


def test_to_relative_writes_a_urdf_recording(files, tmp_path):
    """The converter, as a user runs it: a recording of the chain that `manus fit` reads (its
    URDF named relative to the file), and a one-line error for a file that is not a DFKI export."""
    out = subprocess.run(
        [sys.executable, str(EXAMPLE / "to_relative.py"), str(files[1]), "-o", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    from manus.plants import Serial, recording

    rel = recording.read(out.stdout.strip())
    src = recording.read(files[1])
    assert isinstance(rel.structure, Serial)  # a urdf recording's structure is its chain
    assert rel.structure_name == "urdf" and rel.structure.joint_names == ("shoulder", "elbow")
    np.testing.assert_allclose(rel.q[:, 1], src.q[:, 1] - src.q[:, 0], atol=2 * 3.82e-4)  # relative = θ2 − θ1
    np.testing.assert_allclose(rel.tau @ np.array([[1.0, 0.0], [-1.0, 1.0]]), src.tau, atol=1e-9)  # motors -> absolute
    bad = tmp_path / "plain.csv"
    bad.write_text("# sample_rate_hz: 500\nt,q1,q2,tau1,tau2\n0,0,0,0,0\n0.002,0,0,0,0\n")
    out = subprocess.run(
        [sys.executable, str(EXAMPLE / "to_relative.py"), str(bad), "-o", str(tmp_path)], capture_output=True, text=True
    )
    assert out.returncode == 2 and "not one of the DFKI double pendulum's exports" in out.stderr
    assert "Traceback" not in out.stderr
