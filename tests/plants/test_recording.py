"""Recording files: round trips, the EMPS files, and bad files refused with file, line, problem."""

import warnings

import numpy as np
import pytest

from manus.plants import recording
from manus.plants.errors import RecordingError
from manus.plants.recording import Recording, RecordingWriter

GOOD = """# sample_rate_hz: 1000
# counts_per_rev: 131072
# structure: manus2
# operator: someone
t,q1,q2,tau1,tau2,qd1,qd2,force
0.000,0.4743,2.4051,0.15,1.20,0.60,0.003,1
0.001,0.4749,2.4051,0.16,1.21,0.61,0.004,2
0.002,0.4755,2.4052,0.17,1.22,0.62,0.005,3
"""


def write(tmp_path, text, name="rec.csv", mode="w"):
    p = tmp_path / name
    p.write_bytes(text) if isinstance(text, bytes) else p.write_text(text)
    return p


def test_read_csv_keeps_metadata_and_extra_columns(tmp_path):
    rec = recording.read(write(tmp_path, GOOD))
    assert rec.n_joints == 2 and len(rec) == 3 and rec.has_truth
    assert rec.sample_rate_hz == 1000 and rec.counts_per_rev == 131072 and rec.structure_name == "manus2"
    assert rec.meta["operator"] == "someone"
    np.testing.assert_array_equal(rec.extra["force"], [1, 2, 3])
    np.testing.assert_array_equal(rec.tau[:, 1], [1.20, 1.21, 1.22])


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_round_trip(tmp_path, suffix):
    rng = np.random.default_rng(0)
    t = np.arange(500) * 1e-3
    step = 2 * np.pi / 131072
    rec = Recording(
        t,
        np.round(0.3 * rng.normal(size=(500, 2)) / step) * step,
        rng.normal(size=(500, 2)),
        rng.normal(size=(500, 2)),
        {"sample_rate_hz": "1000", "counts_per_rev": "131072"},
        {"qref1": rng.normal(size=500)},
    )
    back = recording.read(recording.write(rec, tmp_path / f"r{suffix}"))
    for a, b in [
        (rec.t, back.t),
        (rec.q, back.q),
        (rec.tau, back.tau),
        (rec.qd, back.qd),
        (rec.extra["qref1"], back.extra["qref1"]),
    ]:
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-15)
    counts = back.q / step
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)  # still on the grid
    assert back.meta["counts_per_rev"] == "131072"


BAD = {
    "missing column": ("t,q1,q2,tau1\n0,1,2,3\n0.001,1,2,3\n", r"rec.csv: missing column 'tau2'"),
    "nan throughout": ("t,q1,tau1\n0,nan,2\n0.001,nan,2\n0.002,nan,2\n", r"rec.csv: column 'q1' holds no number"),
    "mostly nan": ("t,q1,tau1\n0,1,2\n0.001,nan,2\n0.002,1,inf\n", r"rec.csv:3: column 'q1' is nan .* 2 of 3 samples"),
    "nan time": ("t,q1,tau1\n0,1,2\nnan,1,2\n0.002,1,2\n", r"rec.csv:3: column 't' is nan"),
    "time backwards": ("t,q1,tau1\n0,1,2\n0.002,1,2\n0.001,1,2\n", r"rec.csv:4: time does not increase"),
    "ragged": ("t,q1,tau1\n0,1,2\n0.001,1\n0.002,1,2\n", r"rec.csv:3: ragged row: 2 fields where the header has 3"),
    "empty": ("", r"rec.csv: empty file"),
    "only header": ("t,q1,tau1\n", r"rec.csv:2: no data rows"),
    "binary": (bytes(range(256)) * 10, r"rec.csv: binary file"),
    "text not number": ("t,q1,tau1\n0,1,2\n0.001,1,abc\n", r"rec.csv:3: column 'tau1': 'abc' is not a number"),
    "ms time": ("# sample_rate_hz: 1000\nt,q1,tau1\n0,1,2\n1,1,2\n2,1,2\n", r"is t in milliseconds"),
    "ns time": ("# sample_rate_hz: 1000\nt,q1,tau1\n0,1,2\n1000000,1,2\n2000000,1,2\n", r"is t in nanoseconds"),
    "bad structure": ("# structure: manus2\nt,q1,tau1\n0,1,2\n0.001,1,2\n", r"manus2 has 2 joints"),
    "one sample": ("t,q1,tau1\n0,1,2\n", r"only 1 sample"),
    "duplicate": ("t,q1,q1,tau1\n0,1,1,2\n0.001,1,1,2\n", r"column 'q1' appears twice"),
    "partial truth": ("t,q1,q2,tau1,tau2,qd1\n0,1,1,2,2,0\n0.001,1,1,2,2,0\n", r"missing column 'qd2'"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_files_are_refused_with_file_line_and_problem(tmp_path, case):
    text, message = BAD[case]
    with pytest.raises(RecordingError, match=message):
        recording.read(write(tmp_path, text))


def test_binary_npz_and_mat_are_refused(tmp_path):
    for name in ("rec.npz", "rec.mat"):
        with pytest.raises(RecordingError, match=rf"{name}: not a readable"):
            recording.read(write(tmp_path, b"\x00\x01garbage" * 50, name))
    with pytest.raises(RecordingError, match="no such file"):
        recording.read(tmp_path / "absent.csv")


def test_npz_errors_name_the_sample(tmp_path):
    p = tmp_path / "r.npz"
    np.savez(p, t=np.arange(4) * 1e-3, q1=np.array([0, np.nan, np.nan, np.nan]), tau1=np.zeros(4))
    with pytest.raises(RecordingError, match=r"r.npz sample 1: column 'q1' is nan"):
        recording.read(p)


def test_samples_with_nan_are_lost_samples(tmp_path):
    """A reading the logger did not get (NaN in a position, inf in a torque) makes its sample a
    lost one: dropped at read with one note, then filled and left out like a sample missing from
    the time column. 20 s of the simulated arm with 3 such samples fits to within 0.2 % of the
    whole recording's parameters, and the fit says what it filled."""
    from manus.adaptive import fit
    from manus.experiments import calibration

    rec = calibration.case(
        1, None, structure="arm", rate=1000, excitation="multisine", torque="exact", hold="stated"
    ).rec
    whole = fit(rec, "rigid,viscous,coulomb", method="ls")
    rec.q, rec.tau = rec.q.copy(), rec.tau.copy()
    rec.q[4000, 0], rec.tau[7000, 1], rec.q[9000, 1] = np.nan, np.inf, np.nan
    p = recording.write(rec, tmp_path / "nan.csv")
    with pytest.warns(
        recording.RecordingNote,
        match=r"nan.csv: 3 samples with a NaN or infinite value \(the first at "
        r"line \d+, 'q1' = nan\) read as lost",
    ):
        back = recording.read(p)
    assert len(back) == len(rec) - 3
    f = fit(back, "rigid,viscous,coulomb", method="ls")
    assert "3 samples lost in 3 gaps" in f.data.lost
    for k, v in whole.params.items():
        assert f.params[k] == pytest.approx(v, rel=2e-3), k


def test_incomplete_last_line_is_dropped_with_a_warning(tmp_path):
    p = write(tmp_path, GOOD + "0.003,0.4761,2.40")  # a run killed mid-write
    with pytest.warns(UserWarning, match=r"rec.csv:9: incomplete last line dropped"):
        rec = recording.read(p)
    assert len(rec) == 3
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a complete last line without newline is fine
        assert len(recording.read(write(tmp_path, GOOD + "0.003,0.4761,2.4052,0.18,1.23,0.63,0.006,4"))) == 4


def test_streaming_writer_flushes_and_survives_a_cut(tmp_path):
    p = tmp_path / "live.csv"
    w = RecordingWriter(p, ["t", "q1", "tau1"], {"sample_rate_hz": 1000}, flush_seconds=0.0)
    for k in range(10):
        w.append([k * 1e-3, k * 0.1, -k])
    # not closed (as if killed): everything appended is already in the file
    assert len(recording.read(p)) == 10
    w.close()


def test_emps_files(emps_dir):
    rec = recording.read(emps_dir / "DATA_EMPS.mat")
    assert rec.n_joints == 1 and len(rec) == 24841 and rec.structure_name == "axis"
    assert rec.sample_rate_hz == pytest.approx(1000, rel=1e-3)
    assert float(rec.meta["gtau"]) == pytest.approx(35.15065188)
    np.testing.assert_allclose(rec.tau[:, 0], 35.15065188248547 * rec.extra["vir"])
    pulses = recording.read(emps_dir / "DATA_EMPS_PULSES.mat")
    assert set(pulses.extra) >= {"qg", "vir", "pulses_N"}


def _on_grid(step, n=2000, joints=2):
    """A slow swing quantized on the encoder grid `step`, (n, joints)."""
    t = np.arange(n) * 1e-3
    return np.round(np.stack([0.3 * np.sin(2 * np.pi * 0.7 * t + j) + 0.5 for j in range(joints)], 1) / step) * step


@pytest.mark.parametrize(
    "unit, factor, meta, message",
    [
        ("degrees", 180 / np.pi, {"counts_per_rev": "131072"}, r"57.2958 times .* degrees, not radians\?"),
        ("revolutions", 1 / (2 * np.pi), {"counts_per_rev": "131072"}, r"revolutions, not radians\?"),
        ("counts", 131072 / (2 * np.pi), {"counts_per_rev": "131072"}, r"raw encoder counts, not positions\?"),
        ("millimetres", 1000.0, {"position_step": "1e-06", "joints": "prismatic"}, r"millimetres, not metres\?"),
    ],
)
def test_positions_in_another_unit_than_the_declared_grid_are_refused(tmp_path, unit, factor, meta, message):
    """Positions on the declared encoder grid read; the same positions in another unit (their
    grid a unit's factor off the declared one) are refused, naming the unit."""
    step = float(meta.get("position_step", 0)) or 2 * np.pi / 131072
    q = _on_grid(step)
    base = {"sample_rate_hz": "1000", **meta}
    rec = Recording(np.arange(len(q)) * 1e-3, q, np.ones_like(q), None, base)
    assert recording.read(recording.write(rec, tmp_path / "good.csv")).n_joints == 2
    rec.q = q * factor
    with pytest.raises(RecordingError, match=message):
        recording.read(recording.write(rec, tmp_path / f"{unit}.csv"))


def test_positions_off_the_grid_for_other_reasons_are_read(tmp_path):
    """Noisy or interpolated positions are off the declared grid without a unit's factor: read."""
    step = 2 * np.pi / 131072
    q = _on_grid(step) + np.random.default_rng(0).normal(0, 1e-4, (2000, 2))
    rec = Recording(
        np.arange(2000) * 1e-3, q, np.ones_like(q), None, {"sample_rate_hz": "1000", "counts_per_rev": "131072"}
    )
    assert len(recording.read(recording.write(rec, tmp_path / "noisy.csv"))) == 2000


def test_on_grid_fills_lost_samples_by_interpolation_and_marks_them():
    from manus.plants.gaps import gaps, on_grid

    t = np.r_[np.arange(10), np.arange(13, 20)] * 0.001  # samples 10, 11, 12 lost
    q = np.stack([2 * t, -t], 1)
    rec = Recording(t, q, q.copy(), None, {"sample_rate_hz": "1000"})
    g = gaps(rec)
    assert g.at.tolist() == [10] and g.missing.tolist() == [3]
    grid, filled = on_grid(rec)
    assert len(grid) == 20 and np.allclose(np.diff(grid.t), 0.001)
    assert np.flatnonzero(filled).tolist() == [10, 11, 12]
    assert np.allclose(grid.q[:, 0], 2 * grid.t) and np.allclose(grid.tau[:, 1], -grid.t)
    # positions across a gap by a cubic: a straight line would be off by q̈ (4 ms)²/8 = 7.9e-5 rad here
    swing = Recording(t, np.sin(2 * np.pi * t)[:, None], np.zeros((t.size, 1)), None, {"sample_rate_hz": "1000"})
    assert np.max(np.abs(on_grid(swing)[0].q[:, 0] - np.sin(2 * np.pi * grid.t))) < 1e-9
    same, none = on_grid(Recording(np.arange(5) * 0.001, np.zeros((5, 1)), np.zeros((5, 1))))
    assert len(same) == 5 and not none.any()


def test_an_angle_recorded_modulo_a_turn_is_unwrapped_with_a_note(tmp_path):
    """A joint that spins through nearly two turns, written in [−π, π): read back as it turned (the
    other joint, a prismatic axis in metres, and a recording without wraps are left alone)."""
    t = np.arange(3000) * 1e-3
    turning = 0.5 + 1.2 * t**2  # up to 11.3 rad: over π and 3π
    q = np.stack([(turning + np.pi) % (2 * np.pi) - np.pi, 0.1 * np.sin(t)], 1)
    rec = Recording(t, q, np.zeros_like(q), None, {"sample_rate_hz": "1000"})
    with pytest.warns(recording.RecordingNote, match=r"q1 wraps 2 times by a whole turn \(the first at line \d+\)"):
        back = recording.read(recording.write(rec, tmp_path / "spin.csv"))
    assert np.allclose(back.q[:, 0], turning, atol=1e-9) and np.allclose(back.q[:, 1], q[:, 1])
    slide = Recording(t, np.stack([7 * t], 1), np.zeros((3000, 1)), None, {"joints": "prismatic"})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.allclose(recording.read(recording.write(slide, tmp_path / "slide.csv")).q[:, 0], 7 * t)


def test_a_jump_that_is_neither_motion_nor_a_whole_turn_is_refused(tmp_path):
    t = np.arange(500) * 1e-3
    q = np.stack([0.3 * np.sin(t), 0.2 * t], 1)
    q[200:, 0] += 4.0  # a glitch: 4 rad in one sample, not 2π
    with pytest.raises(RecordingError, match=r"glitch.csv:\d+: q1 jumps by 4 rad in one sample .* degrees\?"):
        recording.read(recording.write(Recording(t, q, np.zeros_like(q)), tmp_path / "glitch.csv"))


def test_a_filled_gap_spoils_its_neighbours_only_where_a_cubic_may_be_off_by_a_count():
    """5/384 |q⁗| (m + 1)⁴ T⁴ against the encoder step (2π/131072 = 4.8e-5 rad): at 1 kHz on a
    2.5 Hz swing of 0.1 rad (|q⁗| up to 2.4e4 rad/s⁴), one lost sample may be off by 5e-9 rad
    (itself left out), fifty by 2e-3 (the guard either side too)."""
    from manus.plants.gaps import spoiled

    t = np.arange(1000) * 1e-3
    w = 2 * np.pi * 2.5
    qdd = np.stack([-0.1 * w**2 * np.sin(w * t)] * 2, 1)
    filled = np.zeros(1000, bool)
    filled[100] = True
    filled[500:550] = True
    out = spoiled(filled, qdd, 1e-3, 2 * np.pi / 131072, guard=20)
    assert np.flatnonzero(out).tolist() == [100] + list(range(480, 570))
    assert spoiled(filled, qdd, 1e-3, 0.0, guard=20)[80:121].all()  # no grid known: always


def test_time_stamps_that_jitter_are_no_gaps_but_lost_samples_among_them_are():
    """Samples taken every period and stamped by a busy clock (late by up to 0.45 T, 20 % RMS):
    no sample is lost, so none is filled (counting each long step as lost samples found 353 in
    10 s and broke the fit); 5 samples lost among such stamps are found, 5."""
    from manus.plants.gaps import gaps, on_grid

    rng = np.random.default_rng(1)
    t = np.arange(10000) * 1e-3 + np.clip(rng.normal(0, 2e-4, 10000), -4.5e-4, 4.5e-4)
    q = np.sin(np.arange(10000) * 1e-3)[:, None]
    rec = Recording(t, q, q.copy(), None, {"sample_rate_hz": "1000"})
    assert not gaps(rec) and len(on_grid(rec)[0]) == 10000
    keep = np.ones(10000, bool)
    keep[4000:4005] = False
    lost = Recording(t[keep], q[keep], q[keep], None, {"sample_rate_hz": "1000"})
    g = gaps(lost)
    assert g.at.tolist() == [4000] and g.missing.tolist() == [5]
    assert len(on_grid(lost)[0]) == 10000
