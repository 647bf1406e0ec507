"""Inputs that used to give garbage with exit 0: a number that JSON has no word for, a digit
separator read as a number, a cut-off the sampling cannot show, a URDF link no rigid body can be."""

import json
import math

import numpy as np
import pytest

from manus.plants.errors import ModelError, RecordingError
from manus.plants.recording import read
from manus.runs.cli import json_text, main

PENDULUM = """<robot name="p">
  <link name="base"/>
  <link name="arm"><inertial><origin xyz="0 0 -0.5"/><mass value="MASS"/>
    <inertia ixx="IXX" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="hinge" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 1 0"/>
    <dynamics damping="DAMPING"/></joint>
</robot>
"""


def test_json_is_strict_whatever_the_numbers():
    r = {"a": float("nan"), "b": [np.float64(np.inf), 1.5], "c": np.array([2.0, -np.inf]), "d": {"e": np.float32(3)}}
    text = json_text(r)
    assert json.loads(text) == {"a": None, "b": [None, 1.5], "c": [2.0, None], "d": {"e": 3.0}}
    assert "NaN" not in text and "Infinity" not in text


def _axis_csv(path, value="0.1", n=400):
    t = np.arange(n) * 1e-3
    lines = ["# structure: axis", "t,q1,tau1"] + [f"{x:.4f},{math.sin(2 * x):.6f},{math.cos(3 * x):.6f}" for x in t]
    lines[10] = f"{t[8]:.4f},{value},0.5"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_digit_separator_is_not_a_number(tmp_path):
    read(_axis_csv(tmp_path / "ok.csv"))
    with pytest.raises(RecordingError, match=r":11: column 'q1': '1_0' is not a number"):
        read(_axis_csv(tmp_path / "sep.csv", "1_0"))


def test_a_cut_off_above_what_the_sampling_shows_is_refused(tmp_path, capsys):
    path = _axis_csv(tmp_path / "rec.csv")
    code = main(["fit", str(path), "--model", "rigid,viscous", "--cutoff", "1e9", "--no-figures"])
    err = capsys.readouterr().err
    assert code == 2 and "cut-off 1e+09 Hz: above what 1000 Hz sampling shows (at most 450 Hz" in err, err


@pytest.mark.parametrize(
    "mass, ixx, damping, words",
    [
        ("-5", "0.01", "0", "link arm: mass -5.0 kg"),
        ("nan", "0.01", "0", "link arm: mass nan kg"),
        ("1", "-0.5", "0", "link arm: an inertia with a negative principal moment (-0.5 kg m²)"),
        ("1", "0.01", "-0.1", "joint hinge: <dynamics damping=-0.1>"),
    ],
)
def test_a_urdf_that_no_rigid_body_can_be_is_refused(tmp_path, mass, ixx, damping, words):
    from manus.plants.serial import Serial

    path = tmp_path / "p.urdf"
    path.write_text(PENDULUM.replace("MASS", mass).replace("IXX", ixx).replace("DAMPING", damping))
    with pytest.raises(ModelError, match=r"p\.urdf: " + words.replace("(", r"\(").replace(")", r"\)")):
        Serial.from_urdf(path)
    path.write_text(PENDULUM.replace("MASS", "1").replace("IXX", "0.01").replace("DAMPING", "0"))
    assert Serial.from_urdf(path).n_joints == 1


def test_a_torque_glitch_is_left_out_and_said():
    """One torque sample of 1e6 N·m (a logger's glitch) in a simulated recording: the fit is the
    clean recording's within one standard deviation (the same motion, the rows drawn around the
    sample left out), its error the same, and the note says what was done."""
    import dataclasses

    from manus.adaptive import fit
    from manus.experiments import calibration

    rec = calibration.case(0, None, rates=(1000,)).rec
    tau = rec.tau.copy()
    tau[len(rec) // 2, 0] = 1e6
    spiked = dataclasses.replace(rec, tau=tau)
    clean, glitched = (fit(r, "rigid,viscous,coulomb", method="ls") for r in (rec, spiked))
    assert clean.data.lost == "" and "1 torque sample far outside the rest" in glitched.data.lost
    assert "tau1 = 1e+06" in glitched.data.lost
    moved = np.abs(glitched.theta - clean.theta) / clean.std
    assert moved.max() < 1.0, dict(zip(clean.names, moved, strict=True))
    assert glitched.rel_error < 1.2 * clean.rel_error  # (a glitch kept in would leave an error of 1e6 N·m in a row)


def test_a_urdf_that_is_not_a_tree_is_refused_at_once(tmp_path):
    """A loop, a self-loop or a chain of thousands of links is refused before any walk (a loop
    reachable from a recording's `# robot:` line walked forever, memory growing)."""
    from manus.plants.serial import MAX_LINKS, Serial

    arm = '<link name="arm"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01"/></inertial></link>'
    hinge = '<joint name="{n}" type="revolute"><parent link="{p}"/><child link="{c}"/><axis xyz="0 1 0"/></joint>'
    cases = {
        "loop": (
            f'<robot name="r"><link name="base"/>{arm}<link name="b"/>'
            + hinge.format(n="j1", p="base", c="arm")
            + hinge.format(n="j2", p="arm", c="b")
            + hinge.format(n="j3", p="b", c="arm")
            + "</robot>",
            "the link 'arm' is the child of two joints (j1, j3)",
        ),
        "self": (
            f'<robot name="r"><link name="base"/>{arm}'
            + hinge.format(n="j1", p="base", c="arm")
            + hinge.format(n="j2", p="arm", c="arm")
            + "</robot>",
            "joint j2 joins the link 'arm' to itself",
        ),
        "deep": (
            '<robot name="r"><link name="l0"/>'
            + "".join(f'<link name="l{i}"/>' for i in range(1, 3000))
            + "".join(
                f'<joint name="f{i}" type="fixed"><parent link="l{i - 1}"/><child link="l{i}"/></joint>'
                for i in range(1, 3000)
            )
            + "</robot>",
            f"3000 links; a robot's URDF has at most {MAX_LINKS} here",
        ),
    }
    for name, (text, words) in cases.items():
        path = tmp_path / f"{name}.urdf"
        path.write_text(text)
        with pytest.raises(ModelError, match=words.replace("(", r"\(").replace(")", r"\)")):
            Serial.from_urdf(path)


def test_an_effect_value_no_recording_can_show_is_refused(tmp_path, capsys):
    path = _axis_csv(tmp_path / "rec.csv", n=8000)
    code = main(["fit", str(path), "--model", "rigid,viscous,cogging:1e12", "--no-figures", "--method", "ls"])
    err = capsys.readouterr().err
    assert code == 2 and "cogging:1e+12: a period of 6.28e-12, under one encoder step" in err, err
    assert main(["fit", str(path), "--model", "rigid,viscous,cogging:3", "--no-figures", "--method", "ls"]) == 0


def test_time_in_milliseconds_is_named(tmp_path):
    """A 1 kHz log whose t is in milliseconds reads as 1 sample per second: refused, the unit named
    (it had given parameters off by 1e3–1e6); a slow recording that states its rate is read."""
    t = np.arange(2000, dtype=float)
    rows = "\n".join(f"{x:g},{math.sin(x / 300):.6f},{math.cos(x / 200):.6f}" for x in t)
    path = tmp_path / "ms.csv"
    path.write_text("# structure: axis\nt,q1,tau1\n" + rows + "\n")
    with pytest.raises(RecordingError, match=r"t advances by 1 per sample: 1 samples per second.*milliseconds"):
        read(path)
    path.write_text("# structure: axis\n# sample_rate_hz: 1\nt,q1,tau1\n" + rows + "\n")
    assert read(path).sample_rate_hz == 1
