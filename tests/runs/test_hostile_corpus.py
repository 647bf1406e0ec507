"""The hostile-input corpus: files and options an ordinary mistake, a logger or an attacker makes,
each given to `manus fit` as a user would. Every one is either analysed right (exit 0, strict
JSON, the axis's inertia within 5 % of the truth the recording was simulated with) or refused
with one line naming the problem (exit 2); none is an internal error, none runs past 60 s.

The recording: a single axis, J q̈ + b q̇ + Fc sign(q̇) = τ (J 0.05 kg m², b 0.2 N·m·s/rad, Fc
0.1 N·m), driven by a multisine at 1 kHz for 4 s, its angle on an encoder of 2¹⁶ counts per turn."""

from __future__ import annotations

import json
import math
import os
import signal

import numpy as np
import pytest

from manus.runs.cli import main
from tests.plants.test_reading import npz_declaring

J, B, FC = 0.05, 0.2, 0.1
RATE, SECONDS, COUNTS = 1000, 4.0, 2**16
TIMEOUT_S = 60


def _simulated() -> np.ndarray:
    """(t, q, tau) rows of the axis, integrated at 20 sub-steps a sample (semi-implicit Euler)."""
    dt, sub = 1.0 / RATE, 20
    t = np.arange(int(SECONDS * RATE)) * dt
    tau = np.zeros_like(t)
    for a, f, p in [(1.0, 0.7, 0.0), (0.6, 1.9, 1.0), (0.4, 4.3, 2.0)]:
        tau += 0.4 * a * np.sin(2 * np.pi * f * t + p)
    q = qd = 0.0
    out = np.empty((t.size, 3))
    h = dt / sub
    for k in range(t.size):
        out[k] = t[k], q, tau[k]
        for _ in range(sub):
            qd += h * (tau[k] - B * qd - FC * math.tanh(qd / 1e-3)) / J
            q += h * qd
    step = 2 * np.pi / COUNTS
    out[:, 1] = np.round(out[:, 1] / step) * step
    return out


ROWS = _simulated()
META = f"# structure: axis\n# sample_rate_hz: {RATE}\n# counts_per_rev: {COUNTS}\n"


def _csv(rows=ROWS, meta=META, header="t,q1,tau1", fmt="{:.12g}", end="\n") -> str:
    return meta + header + "\n" + end.join(",".join(fmt.format(v) for v in r) for r in rows) + end


def _with(rows_change) -> str:
    rows = ROWS.copy()
    rows_change(rows)
    return _csv(rows)


def _set(rows, r, c, v):
    rows[r, c] = v


# name: (what the file holds (text, bytes or a function of the path), extra options, "ok" or words of the refusal)
CORPUS = {
    "clean": (_csv(), [], "ok"),
    "byte order mark": (b"\xef\xbb\xbf" + _csv().encode(), [], "ok"),
    "utf-16": (_csv().encode("utf-16"), [], "ok"),
    "crlf": (_csv(end="\r\n"), [], "ok"),
    "footer": (_csv() + "# stopped_by: limit\n# reason: velocity\n", [], "ok"),
    "cut mid-write": (_csv()[:-7], [], "ok"),
    "torque glitch 1e6": (_with(lambda r: _set(r, 2000, 2, 1e6)), [], "ok"),
    "torque 1e300": (_with(lambda r: _set(r, 2000, 2, 1e300)), [], "ok"),
    "a nan position": (_with(lambda r: _set(r, 1500, 1, np.nan)), [], "ok"),
    "latin-1": (("# operator: Jos\xe9\n" + _csv()).encode("latin-1"), [], "not UTF-8 text: byte 0xe9"),
    "utf-16 without mark": (_csv().encode("utf-16-le"), [], "UTF-16 without a byte order mark"),
    "binary": (bytes(range(256)) * 64, [], "binary file"),
    "empty": ("", [], "empty file"),
    "header only": (META + "t,q1,tau1\n", [], "no data rows"),
    "ragged": (_csv().replace("\n0.5,", "\n0.5,1,", 1), [], "ragged row"),
    "digit separator": (_csv().replace("\n0.5,", "\n0_5,", 1), [], "'0_5' is not a number"),
    "time backwards": (_with(lambda r: _set(r, 100, 0, 0.05)), [], "time does not increase"),
    "time in ms": (
        _with(lambda r: r.__setitem__((slice(None), 0), r[:, 0] * 1000)).replace(META, "# structure: axis\n"),
        [],
        "milliseconds",
    ),
    "degrees, encoder declared": (
        _with(lambda r: r.__setitem__((slice(None), 1), np.degrees(r[:, 1]))),
        [],
        "degrees, not radians",
    ),
    "degrees, nothing declared": (
        _with(lambda r: r.__setitem__((slice(None), 1), np.degrees(r[:, 1]))).replace(
            f"# counts_per_rev: {COUNTS}\n", ""
        ),
        [],
        "degrees, not radians",
    ),
    "offset 1e9 rad": (_with(lambda r: r.__setitem__((slice(None), 1), r[:, 1] + 1e9)), [], "an offset"),
    "torque zero": (
        _with(lambda r: r.__setitem__((slice(None), 2), 0.0)),
        [],
        "the recorded torque is zero throughout",
    ),
    "no motion": (_with(lambda r: r.__setitem__((slice(None), 1), 0.3)), [], "without motion"),
    "structure manus2 on one joint": (
        _csv().replace("structure: axis", "structure: manus2"),
        [],
        "manus2 has 2 joints",
    ),
    "cut-off 1e9": (_csv(), ["--cutoff", "1e9"], "above what 1000 Hz sampling shows"),
    "cut-off negative": (_csv(), ["--cutoff", "-3"], "must be positive"),
    "cogging 1e12": (_csv(), ["--model", "rigid,viscous,coulomb,cogging:1e12"], "under one encoder step"),
    "unknown effect": (_csv(), ["--model", "rigid,wobble"], "wobble"),
    "a directory": (lambda p: p.mkdir(), [], "is a directory"),
    "/dev/zero": (lambda p: p.symlink_to("/dev/zero"), [], "not a regular file"),
    "npz bomb": (lambda p: npz_declaring(p, 10**10), [], "more than the memory budget"),
    "missing": (lambda p: None, [], "no such file"),
}


class _Timeout(Exception):
    pass


@pytest.mark.parametrize("case", list(CORPUS))
def test_each_hostile_input_is_analysed_right_or_refused_in_a_line(case, tmp_path, capsys):
    content, options, expected = CORPUS[case]
    if case == "/dev/zero" and not os.path.exists("/dev/zero"):
        pytest.skip("no /dev/zero")
    path = tmp_path / ("rec.npz" if case == "npz bomb" else "rec.csv")
    if callable(content):
        content(path)
    elif isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    model = [] if "--model" in options else ["--model", "rigid,viscous,coulomb"]
    argv = ["fit", str(path), "--json", "--no-figures", "--method", "ls", *model, *options]

    def late(*_):
        raise _Timeout

    old = signal.signal(signal.SIGALRM, late)
    signal.alarm(TIMEOUT_S)
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's refusal of an option
        code = e.code
    except _Timeout:
        pytest.fail(f"{case}: still running after {TIMEOUT_S} s")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    out, err = capsys.readouterr()
    assert "internal error" not in err and "Traceback" not in err, err
    if expected == "ok":
        assert code == 0, err
        result = json.loads(out)  # strict: no NaN
        assert result["params"]["M1"]["value"] == pytest.approx(J, rel=0.05), (case, result["params"])
    else:
        assert code == 2, (case, code, err)
        last = [line for line in err.strip().splitlines() if line.startswith("manus")][-1]
        assert expected in last, (case, err)
