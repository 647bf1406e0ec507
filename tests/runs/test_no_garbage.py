"""Inputs that used to give garbage with exit 0: a number that JSON has no word for, a digit
separator read as a number, a cut-off the sampling cannot show, a URDF link no rigid body can be,
angles in degrees or offset beyond exact trigonometry."""

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


def _walk(rng, turn, counts, n=4000):
    """An angle's random walk on an encoder of `counts` steps per `turn` (2π: radians, 360:
    degrees), fast then slow (a few steps per sample, where single steps show), written to 12
    digits as manus writes a CSV."""
    step = turn / counts
    fast = rng.normal(0, 0.003, n // 2) * turn / (2 * math.pi)
    x = np.cumsum(np.r_[fast, rng.normal(0, 2 * step, n - n // 2)]) + rng.uniform(-2, 2) * turn / (2 * math.pi)
    return np.array([float(f"{v:.12g}") for v in np.round(x / step) * step])


def test_angles_in_degrees_on_an_encoder_grid_are_named_and_radians_never_are(tmp_path):
    """With no encoder declared, angles whose grid has a whole number of steps per 360 and not
    per 2π are refused as degrees (they had given parameters off by 50-5000x); over 300 seeded
    encoders of 500 to 4 million counts, an encoder in radians is never taken for one, and each
    in degrees is named by its counts; radians printed to a few decimal places are no encoder."""
    rng = np.random.default_rng(7)
    from manus.plants.recording import _grid_in_degrees

    for counts in rng.integers(500, 2**22, 300):
        assert _grid_in_degrees(_walk(rng, 2 * math.pi, counts)) is None, counts
        assert _grid_in_degrees(_walk(rng, 360.0, counts)) == counts, counts
    for places in (2, 3, 4):  # radians printed to a few places: a decimal grid, no encoder's
        assert _grid_in_degrees(np.round(_walk(rng, 2 * math.pi, 2**20), places)) is None
    q = _walk(rng, 360.0, 131072)
    t = np.arange(q.size) * 1e-3
    rows = "\n".join(f"{a:g},{b:.12g},{math.sin(a):.6f}" for a, b in zip(t, q, strict=True))
    path = tmp_path / "deg.csv"
    path.write_text("# structure: axis\n# sample_rate_hz: 1000\nt,q1,tau1\n" + rows + "\n")
    with pytest.raises(RecordingError, match=r"q1 moves on an encoder's grid of 131072 steps per 360.*degrees"):
        read(path)
    path.write_text("# structure: axis\n# sample_rate_hz: 1000\n# joints: prismatic\nt,q1,tau1\n" + rows + "\n")
    assert len(read(path)) == q.size  # (metres on a prismatic axis: no angle, no degrees)


def test_an_angle_beyond_exact_trigonometry_is_refused(tmp_path):
    """Positions offset by 1e9 rad (an internal error from the fit before) are refused, the offset named."""
    t = np.arange(500) * 1e-3
    rows = "\n".join(f"{a:g},{1e9 + math.sin(a):.17g},{math.cos(a):.6f}" for a in t)
    path = tmp_path / "offset.csv"
    path.write_text("# structure: axis\nt,q1,tau1\n" + rows + "\n")
    with pytest.raises(RecordingError, match=r"offset.csv:3: q1 is 1e\+09 rad .* an offset"):
        read(path)


def test_where_a_command_writes_is_checked_before_it_works(tmp_path, capsys):
    """An output that cannot be written is refused when the command line is read (a simulation
    or a run's recording refused after the work would be lost): a directory given for a file,
    a file for a directory, a suffix no recording has."""
    rec = tmp_path / "rec.csv"
    rec.write_text("t,q1,tau1\n0,0,0\n0.001,0,0\n")
    cases = [
        (["simulate", "--seconds", "1", "--out", str(tmp_path)], "a directory; give a file name"),
        (["simulate", "--seconds", "1", "--out", str(tmp_path / "x.txt")], "expected a .csv or .npz file"),
        (["fit", str(rec), "--model", "rigid", "--out", str(rec)], "a file, not a directory"),
        (["run-hardware", "--record", str(tmp_path / "r.npz")], "expected a .csv file"),
        (["simulate", "--out", str(rec / "sub" / "x.csv")], "is a file, not a directory"),
    ]
    for argv, words in cases:
        with pytest.raises(SystemExit) as stop:
            main(argv)
        assert stop.value.code == 2
        assert words in capsys.readouterr().err, argv


def test_a_structure_the_data_contradict_is_said():
    """The thesis arm's recording stated as two independent axes: least squares leaves a third of
    the torque, the arm's own structure about 1 %; a note names the contradiction and the structure
    the data show. Stated as the arm, no note."""
    import dataclasses
    import warnings

    from manus.adaptive import fit
    from manus.experiments import calibration
    from manus.plants.errors import RecordingNote

    rec = calibration.case(0, None, rates=(1000,), structure="arm").rec
    for name, contradicted in (("axis", True), ("manus2", False)):
        stated = dataclasses.replace(rec, meta={**rec.meta, "structure": name})
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            fit(stated, "rigid,viscous,coulomb", method="ls")
        notes = [
            str(w.message) for w in caught if issubclass(w.category, RecordingNote) and "contradict" in str(w.message)
        ]
        assert bool(notes) == contradicted, notes
        assert not notes or "the data contradict `structure: axis`: read as manus2" in notes[0], notes


def _reading_notes(rec, model: str) -> tuple[float, list[str]]:
    import warnings

    from manus.adaptive import fit
    from manus.plants.errors import RecordingNote

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        f = fit(rec, model, method="ls")
    return f.rel_error, [str(w.message) for w in caught if issubclass(w.category, RecordingNote)]


def test_a_chain_logged_in_degrees_is_said():
    """A 6-joint chain's angles logged in degrees, on no grid `read` could check: sines and
    cosines of angles 57 times too large fit next to nothing (90 % of the torque left), the angles
    read in degrees fit as the radians do, and a note says the positions look like degrees. The
    same recording in radians: no note. The thesis's planar arm, whose radians fit is poor
    (a shaft mode ringing) and whose angles read 57 times smaller fit better, is not a chain: no
    note either."""
    import dataclasses

    from manus.experiments import calibration, chains

    rec = chains.case(0).rec  # the UR5 at 100 Hz
    revolute = np.where(np.asarray(rec.prismatic), 1.0, 180 / math.pi)
    degrees = dataclasses.replace(rec, q=rec.q * revolute, qd=None if rec.qd is None else rec.qd * revolute)
    error, notes = _reading_notes(degrees, "rigid,viscous,smooth:0.088")
    assert error > 0.8
    said = [n for n in notes if "look like degrees" in n]
    assert len(said) == 1 and "against" in said[0] and "manus reads radians" in said[0], notes
    error, notes = _reading_notes(rec, "rigid,viscous,smooth:0.088")
    assert error < 0.01 and not any("degrees" in n for n in notes), notes
    arm = calibration.case(4, "compliance", structure="arm").rec
    error, notes = _reading_notes(arm, "rigid,viscous,coulomb")
    assert error > 0.5 and not any("degrees" in n for n in notes), notes


def test_a_chain_torque_in_another_unit_is_said():
    """A chain's torque logged in mN·m fits as well as in N·m, every parameter 1000 times larger:
    its gravity moments, compared with the URDF's, name the scale and the unit. In N·m, or
    scaled by 3 (a URDF's masses may be that far off), no note."""
    import dataclasses

    from manus.experiments import chains

    rec = chains.case(0).rec  # the UR5 at 100 Hz: two gravity moments identified within 10 %
    for scale, said in (
        (1e3, "the torque in mN·m"),
        (1e-3, "the torque in kN·m"),
        (50.0, "a gear ratio"),
        (3.0, None),
        (1.0, None),
    ):
        _, notes = _reading_notes(dataclasses.replace(rec, tau=rec.tau * scale), "rigid,viscous,smooth:0.088")
        moments = [n for n in notes if "gravity moments" in n]
        if said is None:
            assert not moments, (scale, moments)
        else:
            assert len(moments) == 1 and said in moments[0], (scale, notes)
            found = float(moments[0].split("identified ")[1].split(" times")[0])
            assert abs(found / scale - 1) < 0.1, (scale, moments[0])


def test_the_notes_on_a_recording_are_in_the_json_each_time():
    """`manus fit`'s JSON holds the notes its fit raised about the recording (`notes`), every time
    the same analysis runs, and none on a recording with nothing to say."""
    import dataclasses

    from manus.experiments import chains
    from manus.plants.errors import RecordingNote
    from manus.runs.analyses import fit_recording

    rec = chains.case(0).rec
    scaled = dataclasses.replace(rec, tau=rec.tau * 1e3)
    for _ in range(2):
        with pytest.warns(RecordingNote, match="the torque in mN·m"):  # (shown as it is raised, too)
            notes = fit_recording(scaled, "rigid,viscous,smooth:0.088", method="ls").report["notes"]
        assert len(notes) == 1 and "the torque in mN·m" in notes[0], notes
    assert fit_recording(rec, "rigid,viscous,smooth:0.088", method="ls").report["notes"] == []
