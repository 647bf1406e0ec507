"""Compiled functions whose traced program is kept on disk, so that a new process need not trace it.

JAX's persistent compilation cache (`manus.config`) keeps the compiled executables, but a new
process still traces each Python function and lowers it to StableHLO before it can look its
executable up: on a 7-joint arm, about 1.5 s of a `manus diagnose`, spent holding the GIL.
`stored_jit(f)` is `equinox.filter_jit(f)` that also keeps the lowered program (`jax.export`,
serialized) in a folder beside the compilation cache, one file per key. The key is everything the
trace depends on: the manus sources, JAX's version and float64 setting, the devices, the
function, its static arguments (pickled) and the shapes and dtypes of its arrays. A new process
with the same key reads the program and calls it; its executable comes from the compilation
cache. The result is the same to the last bit (the same program compiled the same way).

Where any of that cannot be done (no cache folder, static arguments that do not pickle, a program
`jax.export` refuses, a file that cannot be read or written, a call under another transformation)
the call is the plain `filter_jit`'s: the same result, only slower. The folder is kept under
`LIMIT_BYTES` by deleting its oldest files.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pickle
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
from jax.core import Tracer

LIMIT_BYTES = 512 * 2**20  # the folder's size, beyond which its oldest programs are deleted

_REFUSED: Any = object()  # a key whose program cannot be stored: the plain call, not tried again


def folder() -> Path | None:
    """Where the programs are kept: beside JAX's compilation cache (`manus.config.cache_folder`,
    `<cache>-exported`); None where there is no cache."""
    from manus.config import cache_folder

    cache = cache_folder()
    return None if cache is None else cache.with_name(cache.name + "-exported")


@functools.lru_cache(maxsize=1)
def _sources() -> bytes:
    """A digest of the manus sources and of what traces them: a change to any of them is a new key."""
    h = hashlib.sha256()
    root = Path(__file__).parent
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    h.update(jax.__version__.encode())
    return h.digest()


class Stored:
    """`equinox.filter_jit(fn)` with its lowered program kept on disk (see the module)."""

    def __init__(self, fn: Callable):
        self.fn = fn
        self.jit = eqx.filter_jit(fn)
        self._calls: dict[str, Any] = {}
        self._lock = threading.Lock()
        functools.update_wrapper(self, fn)

    def __call__(self, *args):
        dynamic, static = eqx.partition(args, eqx.is_array)
        leaves, tree = jax.tree.flatten(dynamic)
        where = None if any(isinstance(x, Tracer) for x in leaves) else folder()  # (inside another trace: plain)
        key = None if where is None else self._key(static, tree, leaves)
        if where is None or key is None:
            return self.jit(*args)
        call = self._calls.get(key)
        if call is None:
            call = self._read(where / key, leaves) or self._export(where / key, static, tree, leaves)
            self._calls[key] = call
        return self.jit(*args) if call is _REFUSED else call(*leaves)

    def _key(self, static, tree, leaves) -> str | None:
        """The file name of this call's program (see the module); None where the static arguments
        do not pickle."""
        try:
            blob = pickle.dumps((static, str(tree)), protocol=5)
        except Exception:  # (a lambda or a lock among the static arguments: not a key)
            return None
        h = hashlib.sha256(_sources())
        devices = jax.devices()  # (a trace may split its work over them)
        h.update(f"{self.fn.__module__}.{self.fn.__qualname__} x64={jax.config.read('jax_enable_x64')}".encode())
        h.update(f"{devices[0].platform} x{len(devices)}".encode())
        h.update(blob)
        h.update(repr([(x.shape, str(x.dtype), bool(getattr(x, "weak_type", False))) for x in leaves]).encode())
        return h.hexdigest()

    @staticmethod
    def _read(path: Path, leaves):
        """The stored program at `path`, ready to call on `leaves`; None where there is none, it
        cannot be read or it takes other arrays."""
        try:
            program = jax.export.deserialize(bytearray(path.read_bytes()))
        except Exception:  # (none yet, cut short, or written by another version)
            return None
        takes = [(a.shape, a.dtype) for a in program.in_avals]
        return _callable(program) if takes == [(x.shape, x.dtype) for x in leaves] else None

    def _export(self, path: Path, static, tree, leaves):
        """The program traced and lowered now, written to `path`; `_REFUSED` where it cannot be."""

        def flat(*xs):
            return self.fn(*eqx.combine(jax.tree.unflatten(tree, xs), static))

        flat.__name__, flat.__qualname__ = self.fn.__name__, self.fn.__qualname__  # (as JAX's logs name it)

        weak = [bool(getattr(x, "weak_type", False)) for x in leaves]
        shapes = [jax.ShapeDtypeStruct(x.shape, x.dtype, weak_type=w) for x, w in zip(leaves, weak, strict=True)]
        try:
            program = jax.export.export(jax.jit(flat))(*shapes)
            blob = program.serialize()
        except Exception:  # (a program export refuses: the plain call)
            return _REFUSED
        with self._lock:
            _write(path, bytes(blob))
        return _callable(program)


def _callable(program):
    """The exported `program` compiled to call: on as many devices as a `shard_map` inside it
    splits its work over, its arguments given whole to each."""
    if program.nr_devices == 1:
        return jax.jit(program.call)
    import numpy as np

    mesh = jax.sharding.Mesh(np.array(jax.devices()[: program.nr_devices]), ("devices",))
    whole = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())  # (the program splits them itself)
    return jax.jit(program.call, in_shardings=tuple(whole for _ in program.in_avals))


def _write(path: Path, blob: bytes) -> None:
    """`blob` to `path` whole or not at all (a temporary file renamed), then the folder pruned to
    `LIMIT_BYTES`. A folder that cannot be written is no error: the program is used unstored."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
        tmp.write_bytes(blob)
        os.replace(tmp, path)
        files = sorted((p.stat().st_mtime, p.stat().st_size, p) for p in path.parent.iterdir() if p.is_file())
        total = sum(size for _, size, _ in files)
        for _, size, p in files:
            if total <= LIMIT_BYTES:
                break
            p.unlink(missing_ok=True)
            total -= size
    except OSError:
        pass


def stored_jit(fn: Callable) -> Stored:
    """`equinox.filter_jit(fn)` whose lowered program a new process reads instead of tracing `fn`
    again (arguments positional; see the module)."""
    return Stored(fn)
