"""The `manus` command's contract: --json prints one object on stdout; errors are one line."""

import json

import numpy as np

from manus.plants import recording
from manus.runs.cli import main


def test_simulate_writes_a_readable_recording_with_truth(tmp_path, capsys):
    out = tmp_path / "rec.csv"
    code = main(["simulate", "--truth", "rigid,viscous,coulomb,cogging", "--seconds", "1", "--out", str(out), "--json"])
    captured = capsys.readouterr()
    assert code == 0
    result = json.loads(captured.out)  # nothing else on stdout
    assert result["recording"] == str(out) and result["samples"] == 1000
    assert result["truth"] == "rigid,viscous,coulomb,cogging:39"
    rec = recording.read(out)
    assert rec.has_truth and rec.n_joints == 2 and rec.meta["truth"] == result["truth"]
    assert (tmp_path / "rec.png").stat().st_size > 10000
    assert np.all(np.abs(rec.q - np.stack([rec.extra["qref1"], rec.extra["qref2"]], 1)) < 0.1)


def test_errors_are_one_line_and_non_zero(tmp_path, capsys):
    code = main(["simulate", "--truth", "rigid,glue", "--out", str(tmp_path / "x.csv")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err
    assert err.startswith("manus simulate: unknown effect 'glue'")
    code = main(["simulate", "--param", "Fc9=1", "--out", str(tmp_path / "x.csv")])
    assert code == 2 and "unknown parameter(s) Fc9" in capsys.readouterr().err
