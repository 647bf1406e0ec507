"""`manus diagnose`'s text of a null verdict states the detection limits."""

import contextlib
import io

from manus.experiments import calibration
from manus.plants import recording
from manus.runs.cli import main


def test_a_null_verdict_states_its_detection_limits(tmp_path):
    """A recording with nothing missing and a noisy torque (white, from the calibration set): the
    text of its null verdict states each candidate's detection limit (the share of the torque it
    would have to explain beyond the model's terms to be found 4 times in 5)."""
    c = calibration.case(3, None, structure="arm", rate=1000, excitation="multisine", torque="white", hold="stated")
    path = recording.write(c.rec, tmp_path / "null.npz")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["diagnose", str(path), "--model", c.start, "--no-figures"]) == 0
    text = out.getvalue()
    assert "verdict: null (nothing significant is missing)" in text
    assert "to be found 4 times in 5): " in text
