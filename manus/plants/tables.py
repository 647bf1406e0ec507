"""A user's own tables as recordings: a column map (which of the table's columns is `t`, `q1`,
`tau1`, ... and in which unit), 2-D arrays split into one column per joint, and the sources that
hold tables: Parquet, HDF5 (MATLAB v7.3 files too), MATLAB v5 files by variable name, `.npz`, and
a pandas DataFrame (their files checked and chosen by `manus.plants.sources`).

A column map is text, `t=stamp:ms,q1=shoulder_pos,tau1=shoulder_eff`, or a file of such
`NAME=SOURCE` lines (or a JSON object of them). SOURCE is the table's name for the column (an
HDF5 dataset's path, `/joints/position`); `SOURCE[k]` takes column k (from 0) of a 2-D array;
`:UNIT` converts to SI (`UNITS`). Without a map, a table's names are the recording's (a 2-D array
`q`, `tau`, `qd` or `qref` is split into `q1..qn`, ...).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from manus.plants.reading import fail, memory_budget, over_budget

# a unit's factor to SI, by the kind of quantity it measures
UNITS: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9},
    "position": {"rad": 1.0, "deg": math.pi / 180, "rev": 2 * math.pi, "m": 1.0, "mm": 1e-3},
    "torque": {"Nm": 1.0, "N·m": 1.0, "N": 1.0, "mNm": 1e-3, "kN": 1e3},
    "velocity": {"rad/s": 1.0, "deg/s": math.pi / 180, "rpm": 2 * math.pi / 60, "m/s": 1.0, "mm/s": 1e-3},
}
KINDS = (("t", "time"), ("qref", "position"), ("qd", "velocity"), ("q", "position"), ("tau", "torque"))
SPLIT = ("q", "tau", "qd", "qref")  # 2-D arrays of these names split into one column per joint
NAME = re.compile(r"[A-Za-z_][\w.]*")
ENTRY = re.compile(r"(?P<source>[^\[\]:]+?)\s*(\[\s*(?P<index>\d+)\s*\])?\s*(:\s*(?P<unit>\S+))?")


def _kind(name: str) -> str | None:
    """The kind of quantity a recording's column holds (`t`: time, `q3`: position, ...); None for
    a column of another name (kept as it is)."""
    for prefix, kind in KINDS:
        if name == prefix == "t" or re.fullmatch(prefix + r"\d+", name):
            return kind
    return None


@dataclass(frozen=True)
class Entry:
    """One mapped column: the table's name for it, the column of a 2-D array, the factor to SI."""

    source: str
    index: int | None
    unit: str | None
    scale: float


class ColumnMap:
    """Which of a table's columns is each of the recording's (`parse`)."""

    def __init__(self, entries: dict[str, Entry], text: str):
        self.entries, self.text = entries, text

    @classmethod
    def parse(cls, given: str | Mapping[str, str], flag: str = "--map") -> ColumnMap:
        """A map from text (`t=stamp,q1=pos:deg`), from a file of such lines or a JSON object, or
        from a dict; a `RecordingError` naming the entry for a malformed one."""
        if isinstance(given, Mapping):
            pairs = [(str(k), str(v)) for k, v in given.items()]
            text = ",".join(f"{k}={v}" for k, v in pairs)
        else:
            text = given.strip()
            if "=" not in text:  # a file
                path = Path(text)
                if not path.is_file():
                    fail(flag, None, f"{text!r}: neither NAME=SOURCE pairs nor a file of them")
                content = path.read_text(encoding="utf-8-sig")
                try:
                    obj = json.loads(content)
                except ValueError:
                    obj = None
                if isinstance(obj, dict):
                    return cls.parse({str(k): str(v) for k, v in obj.items()}, f"{flag} {text}")
                lines = [ln.split("#")[0].strip() for ln in content.splitlines()]
                text = ",".join(ln for ln in lines if ln)
            pairs = []
            for item in filter(None, (s.strip() for s in text.split(","))):
                name, sep, value = item.partition("=")
                if not sep:
                    fail(flag, None, f"{item!r}: expected NAME=SOURCE, e.g. t=stamp or q1=position[0]:deg")
                pairs.append((name.strip(), value.strip()))
        entries: dict[str, Entry] = {}
        for name, value in pairs:
            if not NAME.fullmatch(name):
                fail(flag, None, f"{name!r}: not a column name (t, q1, tau1, qd1, qref1 or a name of your own)")
            if name in entries:
                fail(flag, None, f"{name!r} is mapped twice")
            m = ENTRY.fullmatch(value)
            if not value or m is None:
                fail(flag, None, f"{name}={value!r}: expected SOURCE, SOURCE[k] or SOURCE:UNIT")
            unit = m["unit"]
            kind = _kind(name)
            scale = 1.0
            if unit is not None:
                known = UNITS.get(kind or "", {})
                if unit not in known:
                    fail(
                        flag,
                        None,
                        f"{name}={value}: unit {unit!r} is not one of "
                        + (
                            f"{kind}'s: {', '.join(known)}"
                            if known
                            else "a recording column's (t, q, tau, qd, qref take units)"
                        ),
                    )
                scale = known[unit]
            index = None if m["index"] is None else int(m["index"])
            entries[name] = Entry(m["source"].strip(), index, unit, scale)
        if not entries:
            fail(flag, None, "an empty column map")
        return cls(entries, text)

    def said(self) -> str:
        """The map in one line, for notes and metadata."""
        return ", ".join(
            f"{k}={e.source}" + (f"[{e.index}]" if e.index is not None else "") + (f" in {e.unit}" if e.unit else "")
            for k, e in self.entries.items()
        )


class Table:
    """A table's columns by name, each read only when asked for (`get`); `shapes` sized before."""

    def __init__(self, path, shapes: dict[str, tuple[int, ...]], load: Callable[[list[str]], dict[str, np.ndarray]]):
        self.path, self.shapes, self._load = path, shapes, load

    def names(self) -> str:
        """The table's names, for a message."""
        keys = [k for k in self.shapes if not (k.startswith("/") and k[1:] in self.shapes)]
        shown = keys[:20]
        more = f" and {len(keys) - 20} more" if len(keys) > 20 else ""
        return ", ".join(f"{k}{list(self.shapes[k]) if len(self.shapes[k]) > 1 else ''}" for k in shown) + more

    def read(self, names: list[str], numeric_only: bool = False) -> dict[str, np.ndarray]:
        """The columns `names` as floats, their size checked against the memory budget first; a
        column that is not numeric is refused, or left out with `numeric_only` (a table's other
        columns: names, labels)."""
        need = sum(8.0 * float(np.prod(self.shapes[n], dtype=float)) for n in names)
        if need > memory_budget():
            over_budget(self.path, need, "the columns asked for")
        got = self._load(names)
        out = {}
        for n in names:
            a = np.asarray(got[n])
            if a.dtype.kind not in "biuf":
                if numeric_only:
                    continue
                fail(self.path, None, f"column {n!r} is not numeric ({a.dtype})")
            out[n] = a.astype(float)
        return out


def _time_axis(a: np.ndarray, samples: int | None) -> np.ndarray:
    """A 2-D array as (samples, joints): its time axis is the one as long as `t`, else the longer."""
    if samples is not None and a.shape[0] != samples and a.shape[1] == samples:
        return a.T
    if samples is None and a.shape[1] > a.shape[0]:
        return a.T
    return a


def columns(table: Table, cmap: ColumnMap | None) -> dict[str, np.ndarray]:
    """The recording's columns from `table`: by the map, else by the table's own names (1-D
    arrays as they are; 2-D arrays `q`, `tau`, `qd`, `qref` split per joint)."""
    path = table.path
    if cmap is None:
        wanted = [n for n, s in table.shapes.items() if len(s) == 1 or (len(s) == 2 and n in SPLIT)]
        got = table.read(wanted, numeric_only=True)
        samples = len(got["t"]) if "t" in got and got["t"].ndim == 1 else None
        out = {}
        for n, a in got.items():
            if a.ndim == 1:
                out[n] = a
            else:
                a = _time_axis(a, samples)
                out.update({f"{n}{j + 1}": a[:, j] for j in range(a.shape[1])})
        return out
    missing = sorted({e.source for e in cmap.entries.values()} - set(table.shapes))
    if missing:
        fail(path, None, f"the column map names {missing[0]!r}, which the file does not have (it has: {table.names()})")
    got = table.read(sorted({e.source for e in cmap.entries.values()}))
    t_entry = cmap.entries.get("t")
    samples = None
    if t_entry is not None:
        a = got[t_entry.source]
        samples = a.shape[0] if a.ndim == 1 else None
    out = {}
    for name, e in cmap.entries.items():
        a = got[e.source]
        if a.ndim == 2:
            if e.index is None:
                fail(path, None, f"{name}={e.source}: a 2-D array {list(a.shape)}: say which column, {e.source}[k]")
            a = _time_axis(a, samples)
            if e.index >= a.shape[1]:
                fail(path, None, f"{name}={e.source}[{e.index}]: {e.source} has {a.shape[1]} columns (from 0)")
            a = a[:, e.index]
        elif a.ndim != 1 or e.index is not None:
            fail(path, None, f"{name}={e.source}: an array of shape {list(a.shape)}, not a column")
        out[name] = a * e.scale if e.scale != 1.0 else a
    return out


# -- sources ------------------------------------------------------------------------------------
def _needs(extra: str, module: str, what: str):
    """Import `module`, or refuse naming the extra that brings it."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        fail(what, None, f"reading it needs the {extra} extra: pip install 'manus[{extra}]'")


def parquet_table(path: Path) -> tuple[Table, dict[str, str]]:
    """A Parquet file's columns, and its key-value metadata (pandas' own left out)."""
    pq = _needs("formats", "pyarrow.parquet", str(path))
    try:
        f = pq.ParquetFile(path)
        rows = f.metadata.num_rows
        shapes = {name: (rows,) for name in f.schema_arrow.names}
        kv = f.schema_arrow.metadata or {}
    except Exception as e:
        fail(path, None, f"not a readable Parquet file ({type(e).__name__}: {e})")
    meta = {k.decode(): v.decode() for k, v in kv.items() if not k.startswith((b"pandas", b"ARROW"))}

    def load(names):
        t = f.read(columns=names)
        return {n: t.column(n).to_numpy(zero_copy_only=False) for n in names}

    return Table(path, shapes, load), meta


def hdf5_table(path: Path) -> tuple[Table, dict[str, str]]:
    """An HDF5 file's numeric datasets of one or two dimensions, by path (`/group/name`; a
    top-level one by its bare name too, as MATLAB v7.3 variables are), and the root's attributes
    as metadata."""
    h5py = _needs("formats", "h5py", str(path))
    try:
        f = h5py.File(path, "r")
    except Exception as e:
        fail(path, None, f"not a readable HDF5 file ({type(e).__name__}: {e})")
    shapes: dict[str, tuple[int, ...]] = {}
    where: dict[str, str] = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and obj.ndim in (1, 2) and obj.dtype.kind in "biuf" and "#" not in name:
            shape = obj.shape
            if obj.ndim == 2 and 1 in shape:  # a MATLAB vector
                shape = (max(shape),)
            for key in ["/" + name] + ([name] if "/" not in name else []):
                shapes[key], where[key] = shape, name

    f.visititems(visit)
    meta = {}
    for k, v in f.attrs.items():
        v = v.decode() if isinstance(v, bytes) else v
        if isinstance(v, (str, int, float, np.number)):
            meta[k] = str(v)

    def load(names):
        out = {}
        for n in names:
            a = np.asarray(f[where[n]][()])
            out[n] = a.ravel() if len(shapes[n]) == 1 else a
        return out

    return Table(path, shapes, load), meta


def mat5_table(path: Path) -> Table:
    """A MATLAB v5 file's numeric variables by name (vectors as columns), sized from its table of
    contents."""
    from scipy.io import loadmat, whosmat

    try:
        listed = whosmat(path)
    except Exception as e:
        fail(path, None, f"not a readable MATLAB file ({type(e).__name__}: {e})")
    shapes = {}
    for name, shape, kind in listed:
        if kind in ("double", "single", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64"):
            if len(shape) == 2 and 1 in shape:
                shapes[name] = (max(shape),)
            elif len(shape) == 2:
                shapes[name] = tuple(shape)

    def load(names):
        m = loadmat(path, variable_names=names)
        return {n: np.asarray(m[n]).ravel() if len(shapes[n]) == 1 else np.asarray(m[n]) for n in names}

    return Table(path, shapes, load)


def npz_table(path: Path, arrays: dict[str, np.ndarray]) -> tuple[Table, dict[str, str]]:
    """An `.npz`'s arrays (already read, sized from their headers): scalars are metadata."""
    meta, held = {}, {}
    for k, v in arrays.items():
        if v.ndim == 0:
            meta[k] = v.item().decode() if isinstance(v.item(), bytes) else str(v.item())
        else:
            held[k] = v
    for k, v in held.items():
        if v.ndim > 2:
            fail(path, None, f"array {k!r} has shape {list(v.shape)}: expected a column (1-D) or a table (2-D)")
    return Table(path, {k: v.shape for k, v in held.items()}, lambda names: {n: held[n] for n in names}), meta


def is_frame(x) -> bool:
    """A pandas DataFrame (or anything like one: named columns and `to_numpy`), without importing pandas."""
    return hasattr(x, "columns") and hasattr(x, "to_numpy") and hasattr(x, "index")


def frame_table(frame) -> tuple[Table, dict[str, str]]:
    """A DataFrame's columns by name, its index as a column of its name (`index` when unnamed;
    datetimes and durations as seconds), and its `attrs` as metadata."""
    path = "<DataFrame>"
    arrays: dict[str, np.ndarray] = {}
    for c in frame.columns:
        arrays[str(c)] = _seconds(frame[c].to_numpy())
    index = _seconds(np.asarray(frame.index))
    name = str(frame.index.name) if frame.index.name is not None else "index"
    arrays.setdefault(name, index)
    meta = {str(k): str(v) for k, v in getattr(frame, "attrs", {}).items()}
    return Table(path, {k: v.shape for k, v in arrays.items()}, lambda names: {n: arrays[n] for n in names}), meta


def _seconds(a: np.ndarray) -> np.ndarray:
    """Datetimes as seconds from the first, durations as seconds; anything else as it is."""
    if a.dtype.kind == "M":
        ns = a.astype("datetime64[ns]").astype(np.int64)
        return (ns - ns[0]).astype(float) * 1e-9 if ns.size else ns.astype(float)
    if a.dtype.kind == "m":
        return a.astype("timedelta64[ns]").astype(np.int64).astype(float) * 1e-9
    return a
