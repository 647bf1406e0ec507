"""A user's own tables as recordings (`manus.plants.tables` through `recording.read`): a column map
with units, 2-D arrays, and every source that holds a table (CSV, Parquet, HDF5, MATLAB v5 and
v7.3, .npz, a DataFrame). Each is checked against the same known samples, written by the
libraries users write them with (pandas, pyarrow, h5py, scipy)."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pandas as pd
import pytest
import scipy.io

from manus.plants import recording
from manus.plants.errors import RecordingError
from manus.plants.tables import ColumnMap

N = 3000
RATE = 500.0


def _known():
    """t [s], positions [rad] on a 4096-count encoder, torques [N·m]: (time, joint)."""
    t = np.arange(N) / RATE
    step = 2 * math.pi / 4096
    q = np.round(np.stack([np.sin(2 * np.pi * 0.7 * t), 0.5 * np.cos(2 * np.pi * 1.3 * t) + 1], 1) / step) * step
    tau = np.stack([0.8 * np.cos(2 * np.pi * 0.7 * t) + 0.1, -0.3 * np.sin(2 * np.pi * 1.3 * t)], 1)
    return t, q, tau


def _frame():
    t, q, tau = _known()
    return pd.DataFrame(
        {
            "stamp_ms": t * 1e3,
            "shoulder_deg": np.degrees(q[:, 0]),
            "elbow": q[:, 1],
            "shoulder_eff": tau[:, 0],
            "elbow_eff": tau[:, 1],
        }
    )


MAP = "t=stamp_ms:ms,q1=shoulder_deg:deg,q2=elbow,tau1=shoulder_eff,tau2=elbow_eff"


def _same(rec, tol=1e-12):
    t, q, tau = _known()
    assert rec.n_joints == 2 and len(rec) == N
    np.testing.assert_allclose(rec.t, t, atol=tol, rtol=0)
    np.testing.assert_allclose(rec.q, q, atol=tol, rtol=0)
    np.testing.assert_allclose(rec.tau, tau, atol=tol, rtol=0)


def _refused(match, *args, **kwargs):
    with pytest.raises(RecordingError, match=match) as e:
        recording.read(*args, **kwargs)
    assert "\n" not in str(e.value)
    return str(e.value)


def test_a_column_map_reads_names_columns_and_units():
    m = ColumnMap.parse("t = stamp:ms, q1=/log/pos[1]:deg, tau1=eff ,note=free")
    assert m.entries["t"].source == "stamp" and m.entries["t"].scale == 1e-3
    assert m.entries["q1"].source == "/log/pos" and m.entries["q1"].index == 1
    assert m.entries["q1"].scale == pytest.approx(math.pi / 180)
    assert m.entries["tau1"].unit is None and m.entries["note"].source == "free"
    assert ColumnMap.parse({"t": "a", "q1": "b"}).entries["q1"].source == "b"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("t=stamp:kg", "unit 'kg' is not one of time's"),
        ("q1=pos:ms", "unit 'ms' is not one of position's"),
        ("t=a,t=b", "mapped twice"),
        ("1x=a", "not a column name"),
        ("t=", "expected SOURCE"),
        ("t=a,q1", "expected NAME=SOURCE"),
        ("no_such_map_file.txt", "neither NAME=SOURCE pairs nor a file"),
    ],
)
def test_a_malformed_map_is_refused_in_one_line(text, match):
    with pytest.raises(RecordingError, match=match):
        ColumnMap.parse(text)


def test_a_map_file_of_lines_or_json(tmp_path):
    lines = tmp_path / "map.txt"
    lines.write_text("# my logger\nt = stamp_ms:ms\nq1 = shoulder_deg:deg  # degrees\nq2=elbow\ntau1=shoulder_eff\n")
    assert set(ColumnMap.parse(str(lines)).entries) == {"t", "q1", "q2", "tau1"}
    js = tmp_path / "map.json"
    js.write_text('{"t": "stamp_ms:ms", "q1": "shoulder_deg:deg"}')
    assert ColumnMap.parse(str(js)).entries["q1"].unit == "deg"


def test_a_csv_of_other_names_with_a_map_equals_the_known_samples(tmp_path):
    path = tmp_path / "log.csv"
    _frame().to_csv(path, index=False)
    message = _refused("missing column 'q1'", path)
    assert "stamp_ms" in message and "--map" in message  # the file's names and the way out
    rec = recording.read(path, columns=MAP)
    _same(rec)
    assert rec.meta["column_map"].startswith("t=stamp_ms in ms")


def test_a_csv_s_columns_of_words_and_dates_are_not_parsed_when_a_map_leaves_them_out(tmp_path):
    frame = _frame().assign(joint="shoulder", logged_at="2026-11-27T12:00:00.000")
    path = tmp_path / "log.csv"
    frame.to_csv(path, index=False)
    _same(recording.read(path, columns=MAP))
    _refused("column 'joint': 'shoulder' is not a number", path)  # without a map every column is the recording's
    _refused(
        "names 'nope', which the file does not have \\(it has: stamp_ms, .*, joint, logged_at\\)",
        path,
        columns="t=stamp_ms,q1=nope",
    )


def test_parquet_hdf5_mat_npz_and_a_frame_read_the_same_samples(tmp_path):
    frame = _frame()
    frame.to_parquet(tmp_path / "log.parquet")
    _same(recording.read(tmp_path / "log.parquet", columns=MAP))
    _same(recording.read(frame, columns=MAP))

    t, q, tau = _known()
    with h5py.File(tmp_path / "log.h5", "w") as f:
        f["/robot/time"] = t
        f["/robot/joints/position"] = q
        f["/robot/joints/effort"] = tau.T  # (joint, time): the time axis is found by t's length
        f.attrs["counts_per_rev"] = 4096
    rec = recording.read(
        tmp_path / "log.h5",
        columns="t=/robot/time,q1=/robot/joints/position[0],q2=/robot/joints/position[1],"
        "tau1=/robot/joints/effort[0],tau2=/robot/joints/effort[1]",
    )
    _same(rec)
    assert rec.meta["counts_per_rev"] == "4096"  # the root's attributes are metadata

    scipy.io.savemat(tmp_path / "log.mat", {"time": t[:, None], "Q": q, "T": tau})
    _refused("missing column 'q1'.*time, Q\\[3000, 2\\], T\\[3000, 2\\]", tmp_path / "log.mat")
    _same(recording.read(tmp_path / "log.mat", columns="t=time,q1=Q[0],q2=Q[1],tau1=T[0],tau2=T[1]"))

    np.savez(tmp_path / "log.npz", t=t, q=q, tau=tau.T, sample_rate_hz=RATE)  # 2-D arrays split per joint
    rec = recording.read(tmp_path / "log.npz")
    _same(rec)
    assert rec.meta["sample_rate_hz"] == "500.0"


def test_a_matlab_v73_file_is_read_as_hdf5(tmp_path):
    """MATLAB's -v7.3 files are HDF5 behind a 512-byte header; MATLAB stores a T×2 matrix as 2×T."""
    t, q, tau = _known()
    path = tmp_path / "log73.mat"
    with h5py.File(path, "w", userblock_size=512) as f:
        f["time"] = t[None, :]
        f["Q"] = q.T
        f["T"] = tau.T
    with open(path, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Fri Nov 27 2026 HDF5 schema 1.00 .")
    _same(recording.read(path, columns="t=time,q1=Q[0],q2=Q[1],tau1=T[0],tau2=T[1]"))


def test_a_frame_indexed_by_datetimes_and_a_rate_without_time(tmp_path):
    t, q, tau = _known()
    stamps = pd.Timestamp("2026-11-27 12:00:00") + pd.to_timedelta(t, unit="s")
    frame = pd.DataFrame({"q1": q[:, 0], "q2": q[:, 1], "tau1": tau[:, 0], "tau2": tau[:, 1]}, index=stamps)
    frame.index.name = "t"
    _same(recording.read(frame), tol=1e-9)  # the index in seconds from its first (nanosecond datetimes)
    plain = pd.DataFrame({"q1": q[:, 0], "q2": q[:, 1], "tau1": tau[:, 0], "tau2": tau[:, 1]})
    with pytest.warns(UserWarning, match="t made from sample_rate_hz"):
        _same(
            recording.read(
                plain.reset_index(drop=True), columns="q1=q1,q2=q2,tau1=tau1,tau2=tau2", meta={"sample_rate_hz": RATE}
            )
        )
    _refused("missing column 't'.*--set sample_rate_hz", plain, columns="q1=q1,q2=q2,tau1=tau1,tau2=tau2")


def test_what_cannot_be_a_recording_is_refused_in_one_line(tmp_path):
    frame = _frame()
    (tmp_path / "text.parquet").write_text(frame.to_csv(index=False))
    _refused("not a readable Parquet file: it holds text", tmp_path / "text.parquet")
    frame.to_csv(tmp_path / "log.csv", index=False)
    _refused("names 'nope', which the file does not have", tmp_path / "log.csv", columns="t=stamp_ms,q1=nope")
    t, q, tau = _known()
    np.savez(tmp_path / "two.npz", t=t, Q=q, tau1=tau[:, 0], tau2=tau[:, 1])
    _refused("a 2-D array \\[3000, 2\\]: say which column", tmp_path / "two.npz", columns="t=t,q1=Q,tau1=tau1")
    _refused("Q has 2 columns", tmp_path / "two.npz", columns="t=t,q1=Q[2],tau1=tau1")
    ragged = pd.DataFrame({"t": t, "q1": q[:, 0], "tau1": tau[:, 0]})
    np.savez(tmp_path / "ragged.npz", t=t, q1=q[:, 0], tau1=tau[:-5, 0])
    _refused("column 'tau1' has 2995 samples where 't' has 3000", tmp_path / "ragged.npz")
    words = ragged.assign(tau1=["x"] * N)
    _refused("column 'tau1' is not numeric", words, columns="t=t,q1=q1,tau1=tau1")
    labelled = pd.DataFrame({"t": t, "q1": q[:, 0], "tau1": tau[:, 0], "joint": ["shoulder"] * N})
    assert "joint" not in recording.read(labelled).extra  # a column of words, not asked for: left out
    _refused("a ROS 2 bag's", ragged, topic="/joint_states")
    _refused("--topic, --joints and --command-topic are a ROS 2 bag's options", tmp_path / "log.csv", topic="/js")
