"""Which reader a recording's file goes to: its kind read from its first bytes (`sniff`: a name
that says another kind is refused), then a ROS 2 bag (`manus.plants.bag`), a CSV
(`manus.plants.reading`), a table through a column map (`manus.plants.tables`), or the EMPS
benchmark's MATLAB form (`emps`). Each gives the recording's columns, its metadata, where a row
is, and the file's own names (for a message)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from manus.plants import tables
from manus.plants.errors import RecordingError, RecordingNote
from manus.plants.reading import fail, mat_variables, npz_arrays, read_csv, regular_file

PARQUET, HDF5, MATLAB = b"PAR1", b"\x89HDF\r\n\x1a\n", b"MATLAB "


def sniff(path: Path) -> str:
    """What a file holds, by its first bytes: 'parquet', 'hdf5' (MATLAB v7.3 too), 'mat5', 'npz',
    'text', or 'binary' (bytes of no format manus reads: a NUL among the first kilobytes)."""
    with open(path, "rb") as f:
        head = f.read(8)
        if head.startswith(PARQUET):
            return "parquet"
        if head.startswith(HDF5):
            return "hdf5"
        if head.startswith(MATLAB):  # v5, or v7.3: HDF5 behind a 512-byte header
            f.seek(512)
            return "hdf5" if f.read(8) == HDF5 else "mat5"
        if head.startswith(b"PK\x03\x04"):
            return "npz"
        f.seek(0)
        return "binary" if b"\x00" in f.read(4096) else "text"


# what a file's name says it holds, against what its first bytes say (`sniff`)
SUFFIX_KINDS = {
    ".parquet": ("parquet",),
    ".pq": ("parquet",),
    ".h5": ("hdf5",),
    ".hdf5": ("hdf5",),
    ".hdf": ("hdf5",),
    ".mat": ("mat5", "hdf5"),
    ".npz": ("npz",),
}
KIND_NAMES = {
    "parquet": "Parquet",
    "hdf5": "HDF5",
    "mat5": "MATLAB v5",
    "npz": ".npz (zip)",
    "text": "text",
    "binary": "bytes of no format manus reads",
}


def read_file(path: Path, cmap, topic, joints, command_topic):
    """A file's columns (by its names, or by the map), metadata, row locator and names (for a
    message)."""
    if not path.exists():
        raise RecordingError(f"{path}: no such file")
    from manus.plants.bag import is_bag, read_bag

    if is_bag(path):
        if cmap is not None:
            fail(path, None, "a ROS 2 bag's columns come from its JointState messages: no column map applies")
        cols, meta, notes = read_bag(path, topic=topic, joints=joints, command_topic=command_topic)
        for n in notes:
            warnings.warn(f"{path}: {n}", RecordingNote, stacklevel=4)
        return cols, meta, (lambda r: f" sample {r}"), ""
    if path.is_dir():
        raise RecordingError(f"{path}: is a directory, not a recording (nor a ROS 2 bag: no metadata.yaml)")
    if topic or joints or command_topic:
        fail(path, None, "--topic, --joints and --command-topic are a ROS 2 bag's options")
    regular_file(path)
    kind = sniff(path)
    expected = SUFFIX_KINDS.get(path.suffix.lower())
    if expected is not None and kind not in expected:
        fail(
            path,
            None,
            f"not a readable {' or '.join(KIND_NAMES[k] for k in expected)} file: it holds {KIND_NAMES[kind]}"
            + (" (a CSV table? name it .csv)" if kind == "text" else ""),
        )
    sample = lambda r: f" sample {r}"
    if kind in ("text", "binary"):  # (the CSV reader names what is wrong with a binary file)
        wanted = None if cmap is None else {e.source for e in cmap.entries.values()}
        cols, meta, locate, notes = read_csv(path, wanted)  # (with a map, only its columns parsed)
        for n in notes:
            warnings.warn(n, RecordingNote, stacklevel=4)
        table = tables.Table(path, {k: v.shape for k, v in cols.items()}, lambda names: {n: cols[n] for n in names})
        return (cols if cmap is None else tables.columns(table, cmap)), meta, locate, table.names()
    if kind == "npz":
        table, meta = tables.npz_table(path, npz_arrays(path))
    elif kind == "mat5":
        table = tables.mat5_table(path)
        if cmap is None and {"qm", "vir", "gtau"} <= set(table.shapes):
            rec_cols, meta = emps(path)
            return rec_cols, meta, sample, table.names()
        meta = {}
    elif kind == "hdf5":
        table, meta = tables.hdf5_table(path)
    else:
        table, meta = tables.parquet_table(path)
    return tables.columns(table, cmap), meta, sample, table.names()


def emps(path: Path) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """An EMPS benchmark file's columns and metadata: position qm, force gtau·vir, structure axis."""
    m = mat_variables(path, ("t", "qm", "qg", "vir", "gtau", "pulses_N", "kp", "kv"))
    for key in ("t", "qm", "vir", "gtau"):
        if key not in m:
            fail(path, None, f"missing variable {key!r} (an EMPS file has t, qm, qg, vir, gtau)")
    col = lambda k: np.asarray(m[k], float).ravel()
    cols = {"t": col("t"), "q1": col("qm"), "tau1": float(col("gtau")[0]) * col("vir")}
    for k in ("qg", "vir", "pulses_N"):
        if k in m:
            cols[k] = col(k)
    # the reference identification (and the benchmark's own simulator) read vir(k) as acting at t_k
    meta = {
        "structure": "axis",
        "joints": "prismatic",
        "command_hold": "none",
        "source": "EMPS benchmark (Janot, Gautier, Brunot 2019)",
    }
    for k in ("gtau", "kp", "kv"):
        if k in m:
            meta[k] = repr(float(col(k)[0]))
    return cols, meta
