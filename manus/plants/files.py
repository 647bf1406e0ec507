"""Files written whole or not at all: `atomically(path)` gives a temporary name beside `path` to
write to, and puts the file in place only once it is complete (a rename, atomic on one file
system), so a run killed mid-write leaves the previous file or none, never half of one."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomically(path: str | os.PathLike) -> Iterator[Path]:
    """`with atomically(p) as tmp: write(tmp)`: `p` appears complete when the block ends; on an
    error the temporary file is removed and `p` left as it was."""
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
