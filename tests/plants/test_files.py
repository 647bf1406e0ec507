"""Files written whole or not at all (`manus.plants.files.atomically`), as figures, reports and
recordings are written."""

import os

import numpy as np
import pytest

from manus.plants import recording
from manus.plants.files import atomically


def test_a_write_that_fails_leaves_the_old_file_and_no_debris(tmp_path):
    path = tmp_path / "fig.png"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError), atomically(path) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("killed mid-write")
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig.png"]
    with atomically(path) as tmp:
        tmp.write_bytes(b"new")
    assert path.read_bytes() == b"new"
    mask = os.umask(0)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask  # as an ordinary open() makes it


def test_a_recording_that_cannot_be_written_leaves_the_one_before(tmp_path):
    """A write that fails half-way (columns that cannot be stacked into rows) leaves the
    recording written before as it was, and nothing beside it."""
    rec = recording.Recording(np.arange(3) * 1e-3, np.zeros((3, 1)), np.zeros((3, 1)), meta={"structure": "axis"})
    path = recording.write(rec, tmp_path / "r.csv")
    before = path.read_bytes()
    rec.t = np.array([0.0, 1e-3])  # (two stamps for three rows)
    with pytest.raises(ValueError):
        recording.write(rec, path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.csv"]
