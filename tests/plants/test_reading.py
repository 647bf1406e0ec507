"""Reading recordings in bounded time and memory (`manus.plants.reading`): the streamed CSV reader
against numpy's own reading of the whole file, block boundaries anywhere, the encodings a
spreadsheet or a shell writes, files that never end or unpack to far more than their size, and
the memory a large file takes (tracemalloc's peak, numpy's allocations included)."""

import io
import os
import tracemalloc
import zipfile

import numpy as np
import pytest

from manus.plants import reading, recording
from manus.plants.errors import RecordingError

META = "# sample_rate_hz: 1000\n# structure: manus2\n"
HEADER = "t,q1,q2,tau1,tau2\n"


def _rows(n, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    q = np.cumsum(rng.integers(-3, 4, size=(n, 2)), 0) * (2 * np.pi / 131072)  # on an encoder's grid
    return np.column_stack([t, q, rng.normal(size=(n, 2))])


def _text(a, sep="\n"):
    return sep.join(",".join(f"{v:.17g}" for v in row) for row in a) + sep


def _write(tmp_path, text, name="rec.csv"):
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return p


@pytest.mark.parametrize("block", [97, 4096, 1 << 24], ids=["97 B", "4 kB", "16 MB"])
def test_streamed_rows_equal_numpy_reading_the_whole_file(tmp_path, monkeypatch, block):
    """Blocks of any size, blank lines, CRLF line ends and a footer give numpy's rows, and an
    error deep in the file names its line."""
    monkeypatch.setattr(reading, "BLOCK_BYTES", block)
    a = _rows(3000)
    body = _text(a[:1500]) + "\n\n" + _text(a[1500:], sep="\r\n")
    rec = recording.read(_write(tmp_path, META + HEADER + body + "# stopped_by: end\n\n# reason: done\n"))
    ref = np.loadtxt(io.StringIO(body), delimiter=",")
    np.testing.assert_array_equal(rec.t, ref[:, 0])
    np.testing.assert_array_equal(rec.q, ref[:, 1:3])
    np.testing.assert_array_equal(rec.tau, ref[:, 3:5])
    assert rec.meta["stopped_by"] == "end" and rec.meta["reason"] == "done"
    lines = (META + HEADER + body).splitlines()
    bad = lines[:2900] + [lines[2900].replace(",", ",x", 1)] + lines[2901:]  # line 2901 of the file
    with pytest.raises(RecordingError, match=r"rec.csv:2901: column 'q1': 'x.*' is not a number"):
        recording.read(_write(tmp_path, "\n".join(bad) + "\n"))
    with pytest.raises(RecordingError, match=r"rec.csv:2001: ragged row: 4 fields"):
        recording.read(_write(tmp_path, "\n".join(lines[:2000] + ["0,1,2,3"] + lines[2000:]) + "\n"))
    with pytest.raises(RecordingError, match=r"rec.csv:1005: a row after a '#' line"):
        recording.read(_write(tmp_path, "\n".join(lines[:1003] + ["# note: mid", lines[1003]]) + "\n"))


def test_what_editors_and_shells_write_is_read_or_named(tmp_path):
    """A UTF-8 byte order mark (a spreadsheet's CSV) and UTF-16 (PowerShell's `>`) are read as
    the plain file; one Latin-1 character is named by line, column and byte."""
    text = META + HEADER + _text(_rows(200))
    plain = recording.read(_write(tmp_path, text, "plain.csv"))
    for name, raw in [("bom.csv", b"\xef\xbb\xbf" + text.encode()), ("utf16.csv", text.encode("utf-16"))]:
        rec = recording.read(_write(tmp_path, raw, name))
        np.testing.assert_array_equal(rec.q, plain.q)
        assert rec.meta == plain.meta
    latin = ("# operator: Jos\xe9\n" + text).encode("latin-1")
    with pytest.raises(RecordingError, match=r"latin.csv:1: not UTF-8 text: byte 0xe9 at column 16 .*'é'"):
        recording.read(_write(tmp_path, latin, "latin.csv"))
    with pytest.raises(RecordingError, match=r"UTF-16 without a byte order mark"):
        recording.read(_write(tmp_path, text.encode("utf-16-le"), "bare16.csv"))


def npz_declaring(path, samples: int, names=("t", "q1", "tau1")):
    """An `.npz` whose arrays' headers declare `samples` float64 each, with no data behind them."""
    with zipfile.ZipFile(path, "w") as z:
        for name in names:
            with z.open(f"{name}.npy", "w") as f:
                header = np.lib.format.header_data_from_array_1_0(np.zeros(1))
                header["shape"] = (samples,)
                np.lib.format.write_array_header_1_0(f, header)
    return path


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_a_file_that_never_ends_is_refused_at_once(tmp_path, monkeypatch):
    link = tmp_path / "zero.csv"
    link.symlink_to("/dev/zero")
    with pytest.raises(RecordingError, match="not a regular file"):
        recording.read(link)
    monkeypatch.setattr(reading, "LONGEST_LINE", 1000)
    with pytest.raises(RecordingError, match=r"long.csv:4: a line longer than 1000 bytes"):
        recording.read(_write(tmp_path, META + HEADER + "1" * 5000, "long.csv"))


def test_an_npz_that_unpacks_past_the_budget_is_refused_before_it_is_read(tmp_path, monkeypatch):
    """Arrays sized from their headers: 10⁹ samples declared (8 GB) in a file of a few hundred
    bytes are refused naming the budget, without reading a byte of them."""
    monkeypatch.setenv("MANUS_MEMORY_GB", "1")
    path = npz_declaring(tmp_path / "bomb.npz", 10**9)
    assert path.stat().st_size < 2000
    with pytest.raises(RecordingError, match=r"bomb.npz: its arrays would take 24 GB, more than .* budget of 1 GB"):
        recording.read(path)
    monkeypatch.setenv("MANUS_MEMORY_GB", "a lot")
    with pytest.raises(RecordingError, match="MANUS_MEMORY_GB='a lot'"):
        recording.read(path)


def test_rows_past_the_budget_are_refused_as_they_are_read(tmp_path, monkeypatch):
    monkeypatch.setattr(reading, "BLOCK_BYTES", 4096)
    monkeypatch.setenv("MANUS_MEMORY_GB", "1e-5")  # 10 kB: 250 rows of 5 numbers
    with pytest.raises(RecordingError, match=r"its rows \(more than \d+ read so far\) would take .* memory budget"):
        recording.read(_write(tmp_path, META + HEADER + _text(_rows(2000))))


def test_a_large_csv_is_read_in_less_than_three_times_its_size(tmp_path):
    """300 000 rows of a simulated run as manus writes them (about 25 MB, true velocities and
    references included): the peak of what reading allocates, the time base's examination
    included, stays under 3× the file."""
    a = _rows(300_000)
    rec = recording.Recording(
        a[:, 0], a[:, 1:3], a[:, 3:5], a[:, 1:3] * 3.0, {"sample_rate_hz": "1000"}, {"qref1": a[:, 1], "qref2": a[:, 2]}
    )
    path = recording.write(rec, tmp_path / "big.csv")
    tracemalloc.start()
    try:
        back = recording.read(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    np.testing.assert_allclose(back.q, rec.q, rtol=1e-11)
    print(f"read in {peak / path.stat().st_size:.2f}x the file")
    assert peak < 3 * path.stat().st_size, f"{peak / path.stat().st_size:.2f}x the file"


def test_a_matlab_file_past_the_budget_is_refused_before_it_is_read(tmp_path, monkeypatch):
    """An EMPS-form `.mat` is read; with a budget smaller than its variables (sized from its table
    of contents) it is refused, the budget named."""
    from scipy.io import savemat

    n = 1000
    t = np.arange(n) * 1e-3
    path = tmp_path / "emps.mat"
    savemat(path, {"t": t, "qm": np.sin(t), "qg": np.sin(t), "vir": np.cos(t), "gtau": 35.15})
    assert len(recording.read(path)) == n
    monkeypatch.setenv("MANUS_MEMORY_GB", "1e-5")  # 10 kB, under the 32 kB of t, qm, qg and vir
    with pytest.raises(RecordingError, match=r"emps.mat: its variables would take .* memory budget"):
        recording.read(path)
