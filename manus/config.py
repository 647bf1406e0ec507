"""How manus computes, set when it is imported: numpy's BLAS on one thread and XLA's flags (where
numpy and JAX are not running yet), JAX in float64, and JAX's persistent compilation cache. The
library's numerics are float64 throughout: a verdict computed in float32 can differ."""

from __future__ import annotations

import os
from pathlib import Path

# Measured on this CPU (docs/performance.md): compile a whole scan body as one
# function, and expose both cores as devices for sharded batches.
XLA_FLAGS = (
    "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000000",
    "--xla_force_host_platform_device_count=2",
)


def configure_environment() -> None:
    """The environment numpy and JAX read when they start: numpy's small batched solves on one
    BLAS thread (on a busy 2-core machine OpenBLAS's threads spin-wait far longer than these
    products take), `XLA_FLAGS` (kept where already given), and TensorFlow's logging quiet.
    Call it before numpy or JAX is first imported."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    flags = os.environ.get("XLA_FLAGS", "")
    extra = [f for f in XLA_FLAGS if f.split("=")[0] not in flags]
    os.environ["XLA_FLAGS"] = " ".join([flags, *extra]).strip()
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")


def configure() -> None:
    """The environment (`configure_environment`) and JAX in float64 with the compilation cache:
    what every process that imports manus computes with (`manus/__init__` calls it)."""
    configure_environment()
    import jax

    jax.config.update("jax_enable_x64", True)
    _compilation_cache(jax)


CACHE_MIN_COMPILE_S = 0.1  # compilations shorter than this are not worth a file


def cache_folder() -> Path | None:
    """The compilation cache's folder: `MANUS_JAX_CACHE` (default `$XDG_CACHE_HOME/manus/jax`, else
    `~/.cache/manus/jax`; `0` or `off`: none); None where it is off or cannot be made."""
    where = os.environ.get("MANUS_JAX_CACHE", "")
    if where.lower() in ("0", "off"):
        return None
    path = Path(where or os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / ("" if where else "manus/jax")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return path


def _compilation_cache(jax) -> None:
    """JAX's persistent compilation cache in `cache_folder()`, so that a new process finds what an
    earlier one compiled (and `manus.stored` what it traced). JAX keys each entry by the
    computation, its compile options, the XLA flags, the device and JAX's version: a hit is the same
    executable. An entry it cannot read (cut short by a concurrent writer) is a warning and a
    compilation, never a wrong result. A folder that cannot be made leaves the cache off."""
    path = cache_folder()
    if path is None:
        return
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", CACHE_MIN_COMPILE_S)
