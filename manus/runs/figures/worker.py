"""Figures drawn in a second process while the analysis goes on (`Painter`).

A 6–7-joint diagnosis draws about a hundred panels: seconds of matplotlib, all of it Python
holding one core, while the statistics leave the other core mostly idle. A `Painter` with a
worker hands it figure functions (`draw(fn, *args)`: the function and its arguments pickled, the
results of the analysis it draws) and keeps going; each `Job.result()` waits for its figure, or
draws it here where the worker has not started it.
Figures few enough that starting the worker (forked, or where it cannot be, a Python with matplotlib and
JAX: about 2 s of the other core; `_start_method`) would cost more than drawing them are drawn at
once, here: `Painter(panels)` decides from the number of panels the caller expects; a worker
already started draws whatever it is given. The worker is started once per process and
kept for the next command (the test suite runs many); a worker that dies leaves its figures drawn
here."""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

WORKER_PANELS = 40  # panels from which a worker is worth starting (about what 2 s of drawing makes)


@functools.lru_cache(maxsize=1)
def _pool() -> ProcessPoolExecutor:
    return ProcessPoolExecutor(1, mp_context=_start_method(), initializer=_ready)


def _start_method():
    """How the worker starts: forked where this process runs one thread and JAX has started no
    runtime yet (as a command runs when it asks for figures: the worker then has every module this
    process imported, and starts in milliseconds instead of seconds of imports), on Linux; spawned,
    a new Python, anywhere else (a fork of a process with threads or a running XLA can deadlock;
    macOS's system libraries are not safe to fork at all)."""
    import multiprocessing
    import sys
    import threading

    try:
        from jax._src.xla_bridge import backends_are_initialized

        running = backends_are_initialized()
    except ImportError:  # (JAX no longer says: spawn)
        running = True
    quiet = threading.active_count() == 1 and not running and sys.platform.startswith("linux")
    return multiprocessing.get_context("fork" if quiet else "spawn")


def _imported() -> None:
    """matplotlib's figure and Agg canvas and the figure modules imported before the first figure
    is asked for (importing manus sets JAX as `manus` runs it: `manus.config`; a figure may
    evaluate a model). Safe beside other threads: nothing global changes."""
    import importlib

    for module in ("matplotlib.figure", "matplotlib.backends.backend_agg"):
        importlib.import_module(module)
    for module in ("common", "diagnose", "fit"):
        importlib.import_module(f"manus.runs.figures.{module}")


def _ready() -> None:
    """The worker's start: `_imported`, and a small figure drawn in the figures' style, which
    loads the fonts (0.4 s of a process's first figure). Not beside other threads: the style is
    set in matplotlib's global settings while it draws, and the fonts are kept per thread."""
    import io

    _imported()
    from manus.runs.figures.common import panels, styled

    @styled
    def small() -> None:
        fig, axes = panels(1, 1, (1.0, 1.0), "0.0 N·m")
        axes[0, 0].plot([0.0, 1.0], [0.0, 1.0], label="0")
        axes[0, 0].legend()
        axes[0, 0].set_xlabel("t [s]")
        fig.savefig(io.BytesIO(), format="png")

    small()


def _started() -> None:
    """A job that only makes sure the worker is up."""


class Job:
    """A figure being drawn: `result()` waits for it (what its function returned, a path). One the
    worker has not started yet is drawn here instead (the caller asking is free, the worker is
    not), and so is one whose worker died."""

    def __init__(self, fn: Callable, args: tuple, future: Future | None):
        self._fn, self._args, self._future = fn, args, future
        self._value = fn(*args) if future is None else None

    def result(self) -> Any:
        if self._future is not None:
            try:
                self._value = self._fn(*self._args) if self._future.cancel() else self._future.result()
            except BrokenProcessPool:
                _pool.cache_clear()
                self._value = self._fn(*self._args)
            self._future = None
        return self._value


class Painter:
    """Figure functions run beside the analysis (in the worker) or at once (here)."""

    def __init__(self, panels: int):
        started = _pool.cache_info().currsize > 0
        self.remote = panels >= WORKER_PANELS or started  # (or the worker is up already)
        if self.remote and not started:
            self._submit(_started)  # the worker starts now, while the caller works; so do this process's imports
            threading.Thread(target=_imported, name="manus-figures-imported", daemon=True).start()

    def _submit(self, fn: Callable, *args) -> Future | None:
        try:
            return _pool().submit(fn, *args)
        except BrokenProcessPool:
            _pool.cache_clear()
            self.remote = False
            return None

    def draw(self, fn: Callable, *args) -> Job:
        """`fn(*args)` (a figure function; its arguments, the analysis's results, picklable): in
        the worker when there is one, else now."""
        return Job(fn, args, self._submit(fn, *args) if self.remote else None)
