"""Recording files (docs/recording.md): what a rig logged, in CSV, NPZ or the EMPS `.mat` form.

    # sample_rate_hz: 1000
    # counts_per_rev: 131072
    # structure: manus2
    t,q1,q2,tau1,tau2,qd1,qd2
    0.0000,0.474383559,2.405186002,0.155845,1.208326,0.607345,0.003299

Columns: `t` [s]; `q1..qn` measured positions; `tau1..taun` commanded torques; optional
`qd1..qdn` true velocities; any other column is kept in `extra`. A serial robot's recording says
`# structure: urdf` and `# robot: PATH` (its URDF file, relative to the recording; `read(...,
robot=FILE)` and the command line's `--robot FILE.urdf` give or replace it); its joint count must
be the URDF chain's. A file that breaks the rules is
refused with a `RecordingError` naming the file, the line and the problem. One exception, so that
a run killed mid-write is still readable: an incomplete last line (no newline at the end of the
file) is dropped with a warning: when it does not parse as a row, and always in a file whose
metadata says `streamed: true` (a live run's recording, where it may parse yet be cut short).
"""

from __future__ import annotations

import io
import math
import os
import re
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from manus.plants.catalog import structure_named
from manus.plants.errors import RecordingError, RecordingNote
from manus.plants.fastmath import EXACT_BELOW
from manus.plants.files import atomically
from manus.plants.limits import JUMP
from manus.plants.reading import fail
from manus.plants.structures import Structure
from manus.plants.timebase import TimeBase, examine, grid

STRUCTURES = ("manus2", "axis", "urdf")


@dataclass(repr=False)
class Recording:
    t: np.ndarray  # (T,) seconds, strictly increasing
    q: np.ndarray  # (T, n) measured positions
    tau: np.ndarray  # (T, n) commanded torques
    qd: np.ndarray | None = None  # (T, n) true velocities (simulations only)
    meta: dict[str, str] = field(default_factory=dict)
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    path: str = "<memory>"
    # a serial chain read once (structure urdf), or given by whoever made the recording in memory
    serial: Structure | None = field(default=None, repr=False, compare=False)
    # what the stamps and positions said about the true sample grid, where `read` repaired it
    time_base: TimeBase | None = field(default=None, repr=False, compare=False)

    def __repr__(self) -> str:
        """One line (the arrays are for code, not for a notebook's output)."""
        truth = ", true velocities" if self.qd is not None else ""
        extra = f", extra columns {', '.join(self.extra)}" if self.extra else ""
        rate = f" at {self.sample_rate_hz:.6g} Hz" if len(self) >= 2 else ""
        return (
            f"<Recording {self.path}: {len(self)} samples of {self.n_joints} joint(s){rate}, "
            f"structure {self.structure_name}{truth}{extra}>"
        )

    @property
    def n_joints(self) -> int:
        return self.q.shape[1]

    def __len__(self) -> int:
        return self.t.shape[0]

    @property
    def sample_rate_hz(self) -> float:
        if "sample_rate_hz" in self.meta:
            return float(self.meta["sample_rate_hz"])
        return 1.0 / float(np.median(np.diff(self.t)))

    @property
    def dt(self) -> float:
        return 1.0 / self.sample_rate_hz

    @property
    def counts_per_rev(self) -> float | None:
        c = self.meta.get("counts_per_rev")
        return float(c) if c is not None else None

    @property
    def position_step(self) -> float | None:
        """The encoder's grid in position units, when the metadata tells it."""
        if "position_step" in self.meta:
            return float(self.meta["position_step"])
        c = self.counts_per_rev
        return 2 * math.pi / c if c else None

    @property
    def prismatic(self) -> tuple[bool, ...]:
        """Per joint: a linear axis (a serial chain's from its URDF; otherwise metadata `joints`:
        `prismatic` or `revolute`, one for all or one per joint; default revolute)."""
        if self.structure_name == "urdf":
            return tuple(self.structure.prismatic)
        kinds = [k.strip().lower() for k in self.meta.get("joints", "revolute").split(",")]
        kinds = kinds * self.n_joints if len(kinds) == 1 else kinds
        return tuple(k == "prismatic" for k in kinds[: self.n_joints])

    @property
    def hold(self) -> str:
        """How each command was held: `zoh` (over its period, as a digital controller does: the
        default when the file does not say) or `none` (acting at its sample instant only)."""
        return self.meta.get("command_hold", "zoh").strip().lower()

    @property
    def structure_name(self) -> str:
        return self.meta.get("structure") or ("manus2" if self.n_joints == 2 else "axis")

    @property
    def robot(self) -> Path | None:
        """The URDF file of a serial chain (metadata `robot`, relative to the recording's folder;
        an in-memory recording's relative to the working directory)."""
        robot = self.meta.get("robot")
        if not robot:
            return None
        p = Path(robot)
        if p.is_absolute() or self.path == "<memory>":
            return p
        return Path(self.path).parent / p

    @property
    def structure(self) -> Structure:
        """The structure the metadata names, with the transmission its `transmission` states
        (`manus.plants.transmission`: it replaces a URDF's)."""
        if self.structure_name != "urdf":
            return _transmitted(self, structure_named(self.structure_name, self.n_joints))
        if self.serial is None:
            self.serial = _serial_of(self)
        return _transmitted(self, self.serial)

    @property
    def has_truth(self) -> bool:
        return self.qd is not None

    def columns(self) -> dict[str, np.ndarray]:
        cols = {"t": self.t}
        for name, arr in (("q", self.q), ("tau", self.tau), ("qd", self.qd)):
            if arr is not None:
                cols.update({f"{name}{i + 1}": arr[:, i] for i in range(self.n_joints)})
        cols.update(self.extra)
        return cols

    def window(self, start: int, stop: int) -> Recording:
        """Samples start:stop, as a recording of its own."""
        return self.rows(slice(start, stop))

    def rows(self, which) -> Recording:
        """The samples `which` selects (a slice, indices or a mask), as a recording of its own."""
        return Recording(
            self.t[which],
            self.q[which],
            self.tau[which],
            None if self.qd is None else self.qd[which],
            dict(self.meta),
            {k: v[which] for k, v in self.extra.items()},
            self.path,
            self.serial,
            self.time_base,
        )


def _transmitted(rec: Recording, structure: Structure) -> Structure:
    """`structure` with the transmission the metadata states (a `RecordingError` naming the file
    for a malformed one)."""
    from manus.plants.errors import ModelError
    from manus.plants.transmission import stated

    try:
        return stated(structure, rec.meta.get("transmission"), f"{rec.path}: transmission")
    except ModelError as e:
        raise RecordingError(str(e)) from None


def _serial_of(rec: Recording) -> Structure:
    """The serial chain a `structure: urdf` recording names, its joint count checked against the
    recording's; a `RecordingError` naming the recording otherwise."""
    from manus.plants.errors import ModelError

    robot = rec.robot
    if robot is None:
        raise RecordingError(
            f"{rec.path}: structure urdf needs the robot's URDF: a '# robot: PATH' line (relative to "
            "the recording) or --robot FILE.urdf"
        )
    if not robot.is_file():
        raise RecordingError(
            f"{rec.path}: robot {robot}: no such URDF file"
            + (
                f" (the metadata's {rec.meta['robot']!r} is read relative to the recording's folder)"
                if not Path(rec.meta["robot"]).is_absolute()
                else ""
            )
        )
    try:
        return structure_named("urdf", rec.n_joints, robot)
    except ModelError as e:
        raise RecordingError(
            f"{rec.path}: robot {e}" if str(e).startswith(str(robot)) else f"{rec.path}: {e}"
        ) from None


# -- reading ------------------------------------------------------------------------------------


def read(
    source,
    robot: str | os.PathLike | None = None,
    *,
    columns: str | Mapping[str, str] | None = None,
    meta: Mapping[str, object] | None = None,
    topic: str | None = None,
    joints: list[str] | None = None,
    command_topic: str | None = None,
) -> Recording:
    """Read a recording from a file or a table in memory:

    - a manus `.csv` or `.npz`, an EMPS `.mat` file;
    - any CSV, Parquet, HDF5 (MATLAB v7.3 too), MATLAB v5 or `.npz` table, or a pandas DataFrame,
      with `columns`, a column map (`manus.plants.tables.ColumnMap`: `t=stamp:ms,q1=pos[0]`)
      where its names are not the recording's;
    - a ROS 2 bag (a rosbag2 folder, sqlite3 or MCAP) of `sensor_msgs/msg/JointState`: `topic`
      (default the only one), `joints` (names, selected and ordered), `command_topic` (the
      commanded torque, when the states' effort is not it; `manus.plants.bag`).

    `meta` states metadata (`sample_rate_hz`, `counts_per_rev`, `structure`, ...) over the file's
    own. The kind of file is read from its first bytes, and a name that says another kind is
    refused. `robot` (a URDF file) makes it a serial chain's recording (`structure: urdf`),
    whatever its metadata says; a `structure: urdf` recording's URDF is read and its joint count
    checked here."""
    from manus.plants import sources, tables

    cmap = None if columns is None else tables.ColumnMap.parse(columns)
    stated = {str(k): str(v) for k, v in (meta or {}).items()}
    locate: Callable[[int], str] = lambda r: f" sample {r}"
    names = ""
    if tables.is_frame(source):
        if topic or joints or command_topic:
            fail("<DataFrame>", None, "topic, joints and command_topic are a ROS 2 bag's")
        table, file_meta = tables.frame_table(source)
        path: str | Path = table.path
        cols, names = tables.columns(table, cmap), table.names()
    else:
        path = Path(source)
        cols, file_meta, locate, names = sources.read_file(path, cmap, topic, joints, command_topic)
    file_meta.update(stated)
    cols = _timed(path, cols, file_meta, names)
    if cmap is not None:
        file_meta["column_map"] = cmap.said()
    rec = _assemble(path, cols, file_meta, locate)
    if robot is not None:
        rec.meta["structure"] = "urdf"
        rec.meta["robot"] = str(Path(robot).absolute())
        rec.meta.pop("joints", None)  # the URDF says which joints are prismatic
    if rec.structure_name == "urdf":
        rec.structure  # noqa: B018 (read and checked now: a bad robot is the recording's error)
        _angles(rec, lambda r: f" sample {r}")
    elif "transmission" in rec.meta:
        rec.structure  # noqa: B018 (read and checked now: a malformed transmission is the recording's error)
    return _on_its_time_base(rec)


def _timed(path, cols: dict, meta: dict, names: str) -> dict:
    """The columns with `t`: the table's, else made from a stated `sample_rate_hz` (with a note);
    a table without the columns a recording needs is refused naming the ones it has."""
    hint = f" (the file's columns: {names}; map them with --map t=COLUMN,q1=COLUMN,tau1=COLUMN)" if names else ""
    if not any(re.fullmatch(r"q\d+", k) for k in cols):
        fail(path, None, f"missing column 'q1' (measured positions q1..qn){hint}")
    if "t" in cols:
        return _same_length(path, cols)
    if "sample_rate_hz" not in meta:
        fail(path, None, f"missing column 't'{hint}, or state the rate: --set sample_rate_hz=HZ")
    _positive(path, meta, "sample_rate_hz")
    n = len(next(v for k, v in cols.items() if re.fullmatch(r"q\d+", k)))
    warnings.warn(
        f"{path}: no time column: t made from sample_rate_hz ({meta['sample_rate_hz']} Hz)", RecordingNote, stacklevel=4
    )
    return _same_length(path, {"t": np.arange(n) / float(meta["sample_rate_hz"]), **cols})


def _same_length(path, cols: dict) -> dict:
    """The columns, every one as long as `t` (a ragged table refused, naming a column that is not)."""
    n = len(cols["t"])
    odd = next((k for k, v in cols.items() if len(v) != n), None)
    if odd is not None:
        fail(path, None, f"column {odd!r} has {len(cols[odd])} samples where 't' has {n} (ragged)")
    return cols


def _on_its_time_base(rec: Recording) -> Recording:
    """The recording on its true sample grid (`manus.plants.timebase`: repeated rows, jittered or
    alternating stamps, positions held by a resampling, each repaired where the positions show
    the grid), with a note saying what was found; a clean recording as it is."""
    out = repair(rec)
    if out.time_base is not None:
        warnings.warn(f"{rec.path}: {out.time_base.note}", RecordingNote, stacklevel=3)
    return out


def repair(rec: Recording) -> Recording:
    """The recording on its true sample grid, its finding kept (`Recording.time_base`); a clean
    recording comes back as it is (the same object)."""
    tb, keep, stamps = examine(rec)
    if not tb:
        return rec
    out = rec.rows(keep) if not keep.all() else rec.rows(slice(None))
    if stamps is not None:
        out.t = stamps
    if tb.held_every > 1 and tb.repaired and "sample_rate_hz" in out.meta:
        out.meta["sample_rate_hz"] = f"{tb.rate_hz:.12g}"
    return replace(out, time_base=tb)


def _numbered(cols: dict, prefix: str) -> list[int]:
    return sorted(int(m.group(1)) for k in cols if (m := re.fullmatch(prefix + r"(\d+)", k)))


def _assemble(path, cols: dict, meta: dict, locate) -> Recording:
    """Check the columns against the contract and build the Recording. `locate(r)` says where
    data row r is (":123" for a CSV line, " sample 123" for arrays)."""
    if "t" not in cols:
        fail(path, None, "missing column 't'")
    joints = _numbered(cols, "q")
    if not joints:
        fail(path, None, "missing column 'q1' (measured positions q1..qn)")
    n = max(joints)
    for prefix in ("q", "tau"):
        for i in range(1, n + 1):
            if f"{prefix}{i}" not in cols:
                fail(path, None, f"missing column '{prefix}{i}' (the file has q1..q{n})")
    extra_tau = [i for i in _numbered(cols, "tau") if i > n]
    if extra_tau:
        fail(path, None, f"column 'tau{extra_tau[0]}' has no matching 'q{extra_tau[0]}'")
    qd_cols = _numbered(cols, "qd")
    if qd_cols and qd_cols != list(range(1, n + 1)):
        missing = sorted(set(range(1, n + 1)) - set(qd_cols))
        fail(
            path,
            None,
            f"true velocities incomplete: missing column 'qd{missing[0]}'"
            if missing
            else f"column 'qd{max(qd_cols)}' has no matching 'q{max(qd_cols)}'",
        )
    core = ["t"] + [f"{p}{i}" for p in ("q", "tau") + (("qd",) if qd_cols else ()) for i in range(1, n + 1)]
    if (
        "trip" in cols and cols["t"].size > 1 and cols["trip"][-1] == JUMP
    ):  # the hardware loop's stop on an encoder jump
        warnings.warn(
            f"{path}{locate(cols['t'].size - 1)}: the last row left out: its encoder jumped (the run stopped there)",
            RecordingNote,
            stacklevel=3,
        )
        cols = {k: v[:-1] for k, v in cols.items()}
    bad = np.flatnonzero(~np.isfinite(cols["t"]))
    if bad.size:  # (a sample without its time has no place)
        raise RecordingError(f"{path}{locate(bad[0])}: column 't' is {cols['t'][bad[0]]} (NaN or infinite)")
    cols = _drop_missing(path, cols, core[1:], locate)
    t = cols["t"]
    if t.size < 2:
        fail(path, None, f"only {t.size} sample: a recording needs at least 2")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        r = back[0] + 1
        raise RecordingError(f"{path}{locate(r)}: time does not increase (t = {t[r]:.9g} after {t[r - 1]:.9g})")
    meta = {k: str(v) for k, v in meta.items()}
    _check_meta(path, meta, n, t)
    q = np.stack([cols[f"q{i}"] for i in range(1, n + 1)], 1)
    _check_grid(path, meta, q)
    tau = np.stack([cols[f"tau{i}"] for i in range(1, n + 1)], 1)
    qd = np.stack([cols[f"qd{i}"] for i in range(1, n + 1)], 1) if qd_cols else None
    extra = {k: v for k, v in cols.items() if k not in core}
    rec = Recording(t, q, tau, qd, meta, extra, str(path))
    if rec.structure_name != "urdf":  # (a serial chain's joint kinds are its URDF's: once read, in `read`)
        _angles(rec, locate)
    return rec


MISSING_AT_MOST = 0.5  # samples with a NaN read as lost up to this share of the recording; more: refused


def _drop_missing(path, cols: dict, names: list[str], locate) -> dict:
    """A sample with a NaN or infinite position, torque or velocity (a reading the logger did not
    get) is a lost sample: dropped here, with a note, and the analyses fill it and leave it out
    like a sample missing from the time column (`manus.plants.gaps`). More than
    `MISSING_AT_MOST` of the recording missing, or a column missing throughout, is refused."""
    missing = np.zeros(cols["t"].size, bool)
    first: tuple[int, str] | None = None
    for name in names:
        bad = ~np.isfinite(cols[name])
        if bad.all():
            raise RecordingError(f"{path}: column {name!r} holds no number (NaN or infinite throughout)")
        if bad.any() and (first is None or np.argmax(bad) < first[0]):
            first = (int(np.argmax(bad)), name)
        missing |= bad
    k = int(missing.sum())
    if not k or first is None:
        return cols
    where, name = first
    value = cols[name][where]
    if k > MISSING_AT_MOST * missing.size:
        raise RecordingError(
            f"{path}{locate(where)}: column {name!r} is {value} (NaN or infinite), and {k} of "
            f"{missing.size} samples hold such values: too few numbers left to analyse"
        )
    warnings.warn(
        f"{path}: {k} sample{'s' if k != 1 else ''} with a NaN or infinite value (the first at "
        f"{_where(locate(where))}, {name!r} = {value}) read as lost: the analyses fill "
        f"{'them' if k != 1 else 'it'} for the filters and leave {'them' if k != 1 else 'it'} out",
        RecordingNote,
        stacklevel=4,
    )
    keep = ~missing
    return {c: (v[keep] if isinstance(v, np.ndarray) and v.shape[:1] == keep.shape else v) for c, v in cols.items()}


def _where(located: str) -> str:
    """`locate`'s ":123" (a CSV line) or " sample 123", said in a sentence."""
    return f"line {located[1:]}" if located.startswith(":") else located.strip()


def _angles(rec: Recording, locate) -> None:
    """The revolute joints' angles checked and unwrapped. An angle recorded modulo a turn (in
    [−π, π) or [0, 2π): a pendulum that goes over the top) jumps by about 2π between two samples,
    which no joint can move in one period: unwrapped, in place, with a note. A jump of more than
    π that is not a whole number of turns (the neighbouring steps' size off one) is no wrap and
    no motion: refused, by name. So is an angle beyond `EXACT_BELOW` (about 250 000 turns), where
    no sine of it is exact: an offset, raw counts or another unit; and, where no encoder grid is
    declared, angles on an encoder's grid of a whole number of steps per 360 but not per 2π
    (`_grid_in_degrees`)."""
    declared = "counts_per_rev" in rec.meta or "position_step" in rec.meta
    for j, prismatic in enumerate(rec.prismatic):
        far = np.flatnonzero(np.abs(rec.q[:, j]) >= EXACT_BELOW) if not prismatic else np.zeros(0, int)
        if len(far):
            value = rec.q[far[0], j]
            raise RecordingError(
                f"{rec.path}{locate(far[0])}: q{j + 1} is {value:.6g} rad ({value / (2 * math.pi):.3g} turns): "
                f"beyond {EXACT_BELOW:.3g} rad, where an angle's sine and cosine are no longer exact: an "
                "offset, encoder counts or another unit? (manus reads radians; subtract the offset)"
            )
        per_360 = None if prismatic or declared else _grid_in_degrees(rec.q[:, j])
        if per_360:
            raise RecordingError(
                f"{rec.path}: q{j + 1} moves on an encoder's grid of {per_360} steps per 360, a whole "
                f"number, and {per_360 * math.pi / 180:.6g} per 2π: degrees, not radians? manus reads "
                "radians (or state the encoder's counts_per_rev)"
            )
        d = np.diff(rec.q[:, j])
        wraps = np.abs(d) > math.pi
        big = np.flatnonzero(wraps)
        if prismatic or not big.size:
            continue
        small, grid = np.abs(np.where(wraps, 0.0, d)), smallest_step(rec.q[:, j : j + 1])
        for i in big:
            turns = np.rint(d[i] / (2 * math.pi))
            near = max(small[max(i - 2, 0) : i + 3].max(), grid)
            if abs(d[i] - 2 * math.pi * turns) > 3 * near + 1e-9:
                raise RecordingError(
                    f"{rec.path}{locate(i + 1)}: q{j + 1} jumps by {d[i]:.4g} rad in one sample "
                    f"(from {rec.q[i, j]:.6g}); no joint moves that far in one period, and it is not a whole turn "
                    "(an angle wrapped): a glitch of the encoder, or positions in degrees? (manus reads radians)"
                )
        rec.q[:, j] = rec.q[0, j] + np.r_[0.0, np.cumsum(d - 2 * math.pi * np.rint(d / (2 * math.pi)) * wraps)]
        warnings.warn(
            f"{rec.path}: q{j + 1} wraps {big.size} time{'s' if big.size != 1 else ''} by a whole turn "
            f"(the first at {_where(locate(big[0] + 1))}): unwrapped",
            RecordingNote,
            stacklevel=3,
        )


def _positive(path, meta, key):
    if key in meta:
        try:
            v = float(meta[key])
        except ValueError:
            fail(path, None, f"metadata {key}: {meta[key]!r} is not a number")
        if not (v > 0 and math.isfinite(v)):
            fail(path, None, f"metadata {key}: {meta[key]!r} must be positive")


def _check_meta(path, meta, n, t):
    for key in ("sample_rate_hz", "counts_per_rev", "position_step"):
        _positive(path, meta, key)
    structure = meta.get("structure")
    if structure is not None:
        if structure not in STRUCTURES:
            fail(path, None, f"metadata structure: {structure!r} is not one of {', '.join(STRUCTURES)}")
        if structure == "manus2" and n != 2:
            fail(path, None, f"metadata structure: manus2 has 2 joints, the file has {n}")
    if "joints" in meta:
        kinds = [k.strip().lower() for k in meta["joints"].split(",")]
        if any(k not in ("revolute", "prismatic") for k in kinds) or len(kinds) not in (1, n):
            fail(
                path,
                None,
                f"metadata joints: {meta['joints']!r} must be 'revolute' or 'prismatic', one for every "
                f"joint or one per joint ({n})",
            )
    if "command_hold" in meta and meta["command_hold"].strip().lower() not in ("zoh", "none"):
        fail(
            path,
            None,
            f"metadata command_hold: {meta['command_hold']!r} must be 'zoh' (held over the period) "
            "or 'none' (acting at its sample instant)",
        )
    if "sample_rate_hz" in meta:
        rate = float(meta["sample_rate_hz"])
        step = float(np.median(np.diff(t)))
        if abs(step * rate - 1) > 0.01 and abs(_grid_period(t) * rate - 1) > 0.01:
            hint = next(
                (
                    f" (is t in {unit}?)"
                    for factor, unit in ((1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds"))
                    if abs(step * rate / factor - 1) < 0.01
                ),
                "",
            )
            fail(path, None, f"t advances by {step:.6g} per sample but sample_rate_hz is {rate:g}{hint}")
    elif t.size >= 2 and float(np.median(np.diff(t))) >= 1.0 / MIN_RATE_HZ:
        step = float(np.median(np.diff(t)))
        fail(
            path,
            None,
            f"t advances by {step:.6g} per sample: {1 / step:.3g} samples per second, too slow for a robot's "
            f"log (is t in milliseconds? manus reads seconds; a recording this slow states '# sample_rate_hz:')",
        )


MIN_RATE_HZ = 10.0  # a rate under this, not stated in the file, is taken for t in another unit than seconds


def _grid_period(t: np.ndarray) -> float:
    """The period of the uniform grid the stamps scatter around (`manus.plants.timebase.grid`:
    alternating 10/12 ms steps have a median step of 10 or 12 ms, their grid's period is 11)."""
    return grid(t)[2] if t.size >= 4 else float(np.median(np.diff(t)))


def smallest_step(q: np.ndarray) -> float:
    """The smallest non-zero change of the positions (an encoder's grid, where they lie on one); 0
    when they never move."""
    d = np.abs(np.diff(q, axis=0))
    d = d[d > 0]
    return float(d.min()) if d.size else 0.0


GRID_COUNTS = 2**24  # at most this many encoder steps in a turn


def _grid_in_degrees(q: np.ndarray) -> int | None:
    """The steps per 360 of the encoder grid an angle lies on, where that is a whole number (at
    most `GRID_COUNTS`) and the steps per 2π are not: an encoder in degrees. The grid's step is
    read over the angle's whole path (the steps it moved by, each a whole number of the smallest),
    so that numbers written to 12 digits give whole counts to 1e-9 of them. None on no grid
    (filtered, interpolated, noisy positions), on a short decimal's (numbers printed to a few
    places: 0.001 rad), or where the counts are whole in radians."""
    grid = smallest_step(q[:, None])
    if not grid or q.size < 3:
        return None
    d = np.abs(np.diff(q))
    step = float(d.sum() / np.round(d / grid).sum())
    x = (q - q[0]) / step
    if np.mean(np.abs(x - np.round(x)) > 0.05) > 0.5:
        return None
    digits = step / 10.0 ** (math.floor(math.log10(step)) - 1)  # its first two significant digits
    if abs(digits - round(digits)) < 1e-6:
        return None  # a short decimal (0.001, 0.25): numbers printed to a few places, no encoder
    per_360, per_turn = 360.0 / step, 2 * math.pi / step
    whole = lambda c, tol: abs(c - round(c)) < max(tol, 1e-9 * c)  # (to the digits a CSV keeps)
    return round(per_360) if whole(per_360, 1e-3) and per_360 <= GRID_COUNTS and not whole(per_turn, 1e-4) else None


# positions in another unit than the encoder's declared grid: (their grid / the declared one, what it means)
UNIT_SLIPS = (
    (180 / math.pi, "degrees, not radians"),
    (1 / (2 * math.pi), "revolutions, not radians"),
    (1000.0, "millimetres, not metres"),
)


def _check_grid(path, meta, q):
    """Positions the metadata says lie on an encoder's grid (`counts_per_rev`, `position_step`)
    that lie on another, a unit's factor coarser or finer (degrees against radians, millimetres
    against metres, revolutions, raw counts): refused, naming the likely unit. Positions on no
    grid (interpolated, filtered, noisy) or on one of no unit's factor are left alone."""
    key = "position_step" if "position_step" in meta else "counts_per_rev" if "counts_per_rev" in meta else None
    if key is None or q.shape[0] < 3:
        return
    step = float(meta[key]) if key == "position_step" else 2 * math.pi / float(meta[key])
    grid = smallest_step(q)  # the positions' own grid, where they lie on one
    if not grid:
        return
    x = (q - q[0]) / grid
    if np.mean(np.abs(x - np.round(x)) > 0.05) > 0.5:
        return
    slips = UNIT_SLIPS + (((1 / step), "raw encoder counts, not positions"),)
    for factor, what in slips:
        if abs(grid / (step * factor) - 1) < 0.01:
            fail(
                path,
                None,
                f"the positions move in steps of {grid:.6g}, {grid / step:.6g} times the encoder's "
                f"declared step ({step:.6g}, from {key}: {meta[key]}): {what}? manus reads positions in "
                "radians (metres on a prismatic axis)",
            )


# -- writing ------------------------------------------------------------------------------------


def _format(v) -> str:
    return f"{v:.12g}"


def write(rec: Recording, path: str | os.PathLike) -> Path:
    """Write `.csv` or `.npz` (by suffix), whole or not at all (`manus.plants.files.atomically`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cols = rec.columns()
    meta = dict(rec.meta)
    if rec.robot is not None:  # relative to where the file goes
        meta["robot"] = os.path.relpath(rec.robot.absolute(), path.parent.absolute())
    with atomically(path) as tmp:
        if path.suffix.lower() == ".npz":
            with open(tmp, "wb") as f:
                np.savez(f, **cols, **{k: np.asarray(v) for k, v in meta.items()})  # pyright: ignore[reportArgumentType]
        else:
            with RecordingWriter(tmp, list(cols), meta) as w:
                w.append(np.stack(list(cols.values()), 1))
    return path


class RecordingWriter:
    """Writes a CSV recording as a run goes: rows are buffered and flushed to the file at least
    every `flush_seconds`, so a process killed hard leaves everything up to its last flush (and
    at worst one incomplete last line, which `read` drops with a warning)."""

    def __init__(self, path, columns: list[str], meta: dict | None = None, flush_seconds: float = 0.1):
        import time

        self._clock = time.monotonic
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.columns = list(columns)
        self.flush_seconds = flush_seconds
        self._f = open(self.path, "w", buffering=1 << 20)  # noqa: SIM115 (open while the run streams; close() ends it)
        for k, v in (meta or {}).items():
            self._f.write(f"# {k}: {v}\n")
        self._f.write(",".join(self.columns) + "\n")
        self._pending: list[str] = []
        self._last = self._clock()
        self.rows = 0
        self.flush()

    def append(self, rows) -> None:
        rows = np.atleast_2d(np.asarray(rows, float))
        if rows.shape[1] != len(self.columns):
            raise ValueError(f"{self.path}: row of {rows.shape[1]} values for {len(self.columns)} columns")
        buf = io.StringIO()
        np.savetxt(buf, rows, fmt="%.12g", delimiter=",")
        self._pending.append(buf.getvalue())
        self.rows += len(rows)
        if self._clock() - self._last >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        if self._pending:
            self._f.write("".join(self._pending))
            self._pending.clear()
        self._f.flush()
        self._last = self._clock()

    def close(self, footer: dict | None = None) -> None:
        """Write what is pending and close; `footer`: '# key: value' lines after the rows (what the
        run learned at its end: why it stopped), read back into the recording's metadata."""
        if not self._f.closed:
            self.flush()
            for k, v in (footer or {}).items():
                self._f.write(f"# {k}: {' '.join(str(v).split())}\n")
            self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def from_trajectory(
    traj, rate_hz: float, structure: str | Structure, counts_per_rev: float | None = None, meta: dict | None = None
) -> Recording:
    """A recording of a simulated closed-loop run (with its true velocities and reference).
    `structure`: a name, or the structure itself; a serial chain (`Serial`, or its base form)
    makes a `structure: urdf` recording whose `robot` is the chain's URDF file (written relative
    to the recording by `write`)."""
    n = traj.q.shape[1]
    serial = None
    if not isinstance(structure, str):
        serial = structure.standard_form  # a base form's chain
        structure = serial.name
    m = {"sample_rate_hz": f"{rate_hz:g}", "structure": structure, "command_hold": "zoh"}
    if counts_per_rev:
        m["counts_per_rev"] = f"{counts_per_rev:g}"
    if serial is not None and structure == "urdf":
        if not serial.urdf_file:
            raise RecordingError("a serial chain's recording names its URDF file: this chain was not read from one")
        m["robot"] = str(Path(serial.urdf_file).absolute())
    else:
        serial = None
    m.update(meta or {})
    extra = {f"qref{i + 1}": np.asarray(traj.q_ref[:, i]) for i in range(n)}
    return Recording(
        np.asarray(traj.t), np.asarray(traj.q), np.asarray(traj.tau), np.asarray(traj.qd_true), m, extra, serial=serial
    )
