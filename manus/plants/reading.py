"""Reading recording files in bounded time and memory (`manus.plants.recording.read` checks what
they hold).

A CSV is read as a stream: its `# key: value` lines and header line by line, its rows in blocks
of `BLOCK_BYTES` parsed by numpy's C reader (a block that it refuses is read again line by line,
for a message naming the line and the column). What is held never exceeds the memory budget
(`memory_budget`: `MANUS_MEMORY_GB`, else half the machine's memory), and the rows end in one
array about the size of their numbers (8 bytes each), so a file is read in memory about 2× its
size. A UTF-8 byte order mark is skipped, UTF-16 (with its mark) is read as text, a device or a
pipe is refused, and so is a line longer than `LONGEST_LINE` (a file with no line ends). An
`.npz`'s arrays are sized from their headers, and a MATLAB file's variables from its table of
contents, before any is read (a compressed file can unpack to far more than its size)."""

from __future__ import annotations

import io
import os
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NoReturn

import numpy as np

from manus.plants.errors import RecordingError

BLOCK_BYTES = 1 << 22  # rows parsed at a time
LONGEST_LINE = 1 << 20  # a line longer than this is no CSV recording's
BINARY_PROBE = 1 << 16  # bytes looked at for a NUL (a binary file)


def memory_budget() -> float:
    """Bytes a recording may take once read: `MANUS_MEMORY_GB` (GB), else half the machine's
    memory."""
    stated = os.environ.get("MANUS_MEMORY_GB", "").strip()
    if stated:
        try:
            gb = float(stated)
        except ValueError:
            gb = float("nan")
        if not gb > 0:
            raise RecordingError(f"MANUS_MEMORY_GB={stated!r}: expected a positive number of gigabytes")
        return gb * 1e9
    try:
        return 0.5 * os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 4e9


def fail(path, line, problem) -> NoReturn:
    """Refuse a recording: a `RecordingError` naming the file, the line (if any) and the problem."""
    where = f"{path}:{line}" if line else f"{path}"
    raise RecordingError(f"{where}: {problem}")


def over_budget(path, need: float, what: str) -> NoReturn:
    """Refuse what would take `need` bytes, more than the memory budget (`memory_budget`)."""
    fail(
        path,
        None,
        f"{what} would take {need / 1e9:.3g} GB, more than the memory budget of "
        f"{memory_budget() / 1e9:.3g} GB (MANUS_MEMORY_GB sets it; or read a part of the recording)",
    )


def regular_file(path: Path) -> None:
    """A recording is a file: a device (/dev/zero) or a pipe never ends and is refused."""
    if not path.is_file():
        fail(path, None, "not a regular file (a device, a pipe or a socket): a recording is a file")


def _chunks(path: Path) -> Iterator[bytes]:
    """The file's bytes as UTF-8, a block at a time: a UTF-8 byte order mark dropped, UTF-16 with
    its mark transcoded."""
    with open(path, "rb") as f:
        head = f.read(BINARY_PROBE)
        if head.startswith((b"\xff\xfe", b"\xfe\xff")):
            f.seek(0)
            text = io.TextIOWrapper(f, encoding="utf-16", newline="")
            try:
                while chunk := text.read(BLOCK_BYTES // 2):
                    yield chunk.encode("utf-8")
            except UnicodeDecodeError as e:
                fail(path, None, f"UTF-16 text that does not decode ({e.reason}): a corrupted file")
            return
        if b"\x00" in head:
            hint = (
                " (UTF-16 without a byte order mark? save it as UTF-8)" if head[1::2].count(0) > len(head) // 4 else ""
            )
            fail(
                path,
                None,
                f"binary file, not a CSV recording{hint} (expected text: '# key: value' lines, a header, rows)",
            )
        yield head.removeprefix(b"\xef\xbb\xbf")
        while chunk := f.read(BLOCK_BYTES):
            yield chunk


class _Text:
    """Lines and blocks of lines from `_chunks`, counting lines (1-based, as an editor shows them)."""

    def __init__(self, path: Path):
        self.path, self._chunks, self._buf, self.line = path, _chunks(path), b"", 0

    def _more(self) -> bool:
        chunk = next(self._chunks, None)
        if chunk is None:
            return False
        self._buf += chunk
        return True

    def readline(self) -> bytes | None:
        """The next line without its end; None at the end of the file."""
        while (end := self._buf.find(b"\n")) < 0:
            if len(self._buf) > LONGEST_LINE:
                self._too_long()
            if not self._more():
                if not self._buf:
                    return None
                end = len(self._buf)
                break
        line, self._buf = self._buf[:end], self._buf[end + 1 :]
        self.line += 1
        return line

    def block(self) -> tuple[bytes, int, bool]:
        """The next lines, about `BLOCK_BYTES`, ending with a line end, and the number of the
        first; at the end of a file that does not end with one, its unterminated last line and
        True; (b'', ·, True) after everything."""
        while len(self._buf) < BLOCK_BYTES and self._more():
            pass
        while (end := self._buf.rfind(b"\n")) < 0 and len(self._buf) <= LONGEST_LINE and self._more():
            pass
        first = self.line + 1
        if end < 0:
            if len(self._buf) > LONGEST_LINE:
                self._too_long()
            tail, self._buf = self._buf, b""
            self.line += bool(tail)
            return tail, first, True
        out, self._buf = self._buf[: end + 1], self._buf[end + 1 :]
        self.line += out.count(b"\n")
        return out, first, False

    def _too_long(self) -> NoReturn:
        fail(self.path, self.line + 1, f"a line longer than {LONGEST_LINE} bytes: not a CSV recording")


def decoded(path, lineno: int, raw: bytes) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        byte = raw[e.start]
        guess = bytes([byte]).decode("latin-1")
        fail(
            path,
            lineno,
            f"not UTF-8 text: byte 0x{byte:02x} at column {e.start + 1} (a Latin-1 or Windows "
            f"{guess!r}? save the file as UTF-8)",
        )


def is_number(x: str) -> bool:
    """A number as a CSV writes one (Python's `float` also takes '1_0' for 10: not here)."""
    if "_" in x:
        return False
    try:
        float(x)
        return True
    except ValueError:
        return False


def row_ok(line: str, ncol: int, use: list[int] | None = None) -> bool:
    """A row of `ncol` fields, numbers in the columns `use` (default all)."""
    fields = line.split(",")
    return len(fields) == ncol and all(is_number(fields[j]) for j in (range(ncol) if use is None else use))


def _check_header(path, lineno, header):
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        fail(path, lineno, f"column {dup[0]!r} appears twice in the header")
    if "" in header:
        fail(path, lineno, "empty column name in the header")


class _Rows:
    """Parsed blocks of rows (the columns `use` of each) and where each row is in the file."""

    def __init__(self, path, header: list[str], use: list[int]):
        self.path, self.header, self.ncol, self.use = path, header, len(header), use
        self.blocks: list[np.ndarray] = []
        # per block: its first row, the line of that row, and each row's line (None: consecutive)
        self.lines: list[tuple[int, int, np.ndarray | None]] = []
        self.rows = 0
        self.budget = memory_budget()

    def add(self, block: bytes, first_line: int) -> None:
        """Rows of `block` (complete lines; `first_line` the number of its first)."""
        if not block.strip():
            return
        try:
            some = len(self.use) < self.ncol
            a = np.loadtxt(
                io.BytesIO(block),
                delimiter=",",
                ndmin=2,
                comments=None,
                dtype=float,
                usecols=self.use if some else None,
            )
            if a.shape[1] != len(self.use) or (some and block[: block.find(b"\n")].count(b",") != self.ncol - 1):
                raise ValueError("ragged")
            lines = (
                None
                if len(a) == block.count(b"\n") + (not block.endswith(b"\n"))
                else self._line_numbers(block, first_line)
            )
        except ValueError:
            a, lines = self._slowly(block, first_line)
        if not len(a):
            return
        self.lines.append((self.rows, first_line, lines))
        self.blocks.append(a)
        self.rows += len(a)
        if 8.0 * self.rows * len(self.use) > self.budget:
            over_budget(self.path, 8.0 * self.rows * len(self.use), f"its rows (more than {self.rows} read so far)")

    @staticmethod
    def _line_numbers(block: bytes, first_line: int) -> np.ndarray:
        return np.array([first_line + i for i, s in enumerate(block.split(b"\n")) if s.strip()], dtype=np.int64)

    def _slowly(self, block: bytes, first_line: int) -> tuple[np.ndarray, np.ndarray]:
        """The block line by line: the rows, or the first problem named at its line and column."""
        out, lines = [], []
        for i, raw in enumerate(block.split(b"\n")):
            lineno = first_line + i
            line = decoded(self.path, lineno, raw)
            if not line.strip():
                continue
            fields = line.split(",")
            if len(fields) != self.ncol:
                fail(self.path, lineno, f"ragged row: {len(fields)} fields where the header has {self.ncol}")
            bad = next((j for j in self.use if not is_number(fields[j])), None)
            if bad is not None:
                fail(self.path, lineno, f"column {self.header[bad]!r}: {fields[bad].strip()!r} is not a number")
            out.append([float(fields[j]) for j in self.use])
            lines.append(lineno)
        return np.array(out, dtype=float).reshape(-1, len(self.use)), np.array(lines, dtype=np.int64)

    def columns(self) -> list[np.ndarray]:
        """The rows as one array per column, each block released as it is copied (the numbers
        held at most once and a block)."""
        cols = [np.empty(self.rows) for _ in self.use]
        at = 0
        while self.blocks:
            a = self.blocks.pop(0)
            for j, c in enumerate(cols):
                c[at : at + len(a)] = a[:, j]
            at += len(a)
        return cols

    def where(self, r: int) -> int:
        """The line of row r."""
        for first, start, lines in reversed(self.lines):
            if r >= first:
                return start + (r - first) if lines is None else int(lines[r - first])
        return 0


def read_csv(
    path: Path, wanted: set[str] | None = None
) -> tuple[dict[str, np.ndarray], dict[str, str], Callable[[int], str], list[str]]:
    """A CSV recording's columns (those named in `wanted` where given: the others, words or
    dates, are not parsed), its metadata (the `# key: value` lines above the header and after
    the rows), where a data row is (`locate(r)`: ":LINE") and notes on what was repaired as it
    was read (an incomplete last line dropped)."""
    regular_file(path)
    text = _Text(path)
    meta: dict[str, str] = {}
    header: list[str] | None = None
    anything = False
    while (raw := text.readline()) is not None:
        line = decoded(path, text.line, raw)
        s = line.strip()
        anything = anything or bool(s)
        if not s:
            continue
        if s.startswith("#"):
            key, sep, value = s[1:].partition(":")
            if sep:
                meta[key.strip()] = value.strip()
            continue
        header = [h.strip() for h in line.split(",")]
        break
    if header is None:
        fail(path, None, "no header row (expected e.g. 't,q1,q2,tau1,tau2')" if anything else "empty file")
    header_line = text.line
    _check_header(path, header_line, header)
    absent = sorted((wanted or set()) - set(header))
    if absent:
        fail(
            path,
            None,
            f"the column map names {absent[0]!r}, which the file does not have (it has: {', '.join(header)})",
        )
    use = [j for j, h in enumerate(header) if wanted is None or h in wanted]
    rows = _Rows(path, header, use)
    notes: list[str] = []
    footer: list[tuple[int, str]] = []
    while True:
        block, first, last = text.block()
        if not block:
            break
        if footer:  # after the footer's first line, only '# key: value' lines
            footer += _footer_lines(path, block, first)
            continue
        at = block.find(b"#")
        start = block.rfind(b"\n", 0, at) + 1
        if at >= 0 and not block[start:at].strip():  # a streamed run's footer: '# key: value' lines after the rows
            footer += _footer_lines(path, block[start:], first + block[:start].count(b"\n"))
            rows.add(block[:start], first)
            continue
        if not last:
            rows.add(block, first)
            continue
        # the file's last line, with no line end after it: a run killed mid-write
        tail = decoded(path, first, block)
        if tail.strip():
            if not row_ok(tail, len(header), use) or meta.get("streamed", "").lower() == "true":
                notes.append(f"{path}:{first}: incomplete last line dropped (the file was cut mid-write)")
            else:
                rows.add(block + b"\n", first)
    for _, line in footer:
        key, sep, value = line.strip()[1:].partition(":")
        if sep:
            meta[key.strip()] = value.strip()
    if not rows.rows:
        fail(path, header_line + 1, "no data rows after the header")
    names = [header[j] for j in use]
    return dict(zip(names, rows.columns(), strict=True)), meta, lambda r: f":{rows.where(r)}", notes


def _footer_lines(path, block: bytes, first: int) -> list[tuple[int, str]]:
    """A streamed run's footer: '# key: value' lines after the rows (blank lines allowed); a row
    among or after them is refused."""
    out = []
    for i, raw in enumerate(block.split(b"\n")):
        line = decoded(path, first + i, raw)
        if not line.strip():
            continue
        if not line.lstrip().startswith("#"):
            fail(
                path, first + i, "a row after a '#' line: '# key: value' lines go above the header, or after every row"
            )
        out.append((first + i, line))
    return out


def npz_arrays(path: Path) -> dict[str, np.ndarray]:
    """An `.npz`'s arrays, each sized from its header first: what would exceed the memory budget
    (a compressed file can unpack to far more than its size) is refused before it is read."""
    regular_file(path)
    try:
        need = 0.0
        with zipfile.ZipFile(path) as z:
            for info in z.infolist():
                with z.open(info) as f:
                    version = np.lib.format.read_magic(f)
                    read_header = (
                        np.lib.format.read_array_header_1_0
                        if version == (1, 0)
                        else np.lib.format.read_array_header_2_0
                    )
                    shape, _, dtype = read_header(f)
                    need += float(np.prod(shape, dtype=float)) * max(dtype.itemsize, 8)
        if need > memory_budget():
            over_budget(path, need, "its arrays")
        with np.load(path, allow_pickle=False) as z:
            return {k: np.asarray(z[k]) for k in z.files}
    except RecordingError:
        raise
    except Exception as e:  # a zip that is not one, a pickle, a truncated file
        fail(path, None, f"not a readable .npz recording ({type(e).__name__}: {e})")


def mat_variables(path: Path, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The variables `names` of a MATLAB file (those it has), sized from its table of contents
    before any is read: what would exceed the memory budget is refused unread."""
    regular_file(path)
    from scipy.io import loadmat, whosmat

    try:
        listed = whosmat(path)
        need = sum(float(np.prod(shape, dtype=float)) * 8 for name, shape, _ in listed if name in names)
        if need > memory_budget():
            over_budget(path, need, "its variables")
        return loadmat(path, variable_names=[n for n, *_ in listed if n in names])
    except RecordingError:
        raise
    except Exception as e:  # not a MATLAB file, a truncated one, a version scipy cannot read
        fail(path, None, f"not a readable MATLAB file ({type(e).__name__}: {e})")
