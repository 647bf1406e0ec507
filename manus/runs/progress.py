"""What the commands say while they work, on stderr: notes, progress bars with the time left, a
stage's seconds, and what reading a recording noted as one line each; all silenced by
`set_quiet` (`--json` without `--progress`)."""

from __future__ import annotations

import contextlib
import sys
import warnings

_QUIET = {"on": False}


def set_quiet(on: bool) -> None:
    """Silence the notes and the progress bars (`--json` without `--progress`)."""
    _QUIET["on"] = on


def quiet() -> bool:
    """Whether notes and progress are silenced."""
    return _QUIET["on"]


def note(*parts) -> None:
    """A progress note or remark for the person at the terminal: stderr, never stdout; nothing
    when silenced (`set_quiet`)."""
    if not _QUIET["on"]:
        print(*parts, file=sys.stderr, flush=True)


class Bar:
    """A `(done, total)` callback that draws a progress bar with its estimate of the time left
    (tqdm) on stderr, under a stage's name; a new bar where the count starts again. Silent when
    notes are."""

    def __init__(self, desc: str, unit: str = "step"):
        self.desc, self.unit = desc, unit
        self.bar = None

    def __call__(self, done: int, total: int) -> None:
        if _QUIET["on"] or total < 1:
            return
        from tqdm import tqdm

        if self.bar is None or done == 0 or self.bar.total != total:
            self.close()
            self.bar = tqdm(
                total=total, desc=self.desc, unit=self.unit, file=sys.stderr, leave=False, mininterval=0.5, delay=1.0
            )
        self.bar.update(done - self.bar.n)
        if done >= total:
            self.close()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


@contextlib.contextmanager
def elapsed(desc: str, about_s: float | None = None):
    """A stage whose progress cannot be counted (one compiled computation): a line that counts the
    seconds on stderr while it runs, against `about_s` where an estimate is known; silent when
    notes are."""
    import threading
    import time

    if _QUIET["on"]:
        yield
        return
    from tqdm import tqdm

    start, done = time.perf_counter(), threading.Event()
    total = None if about_s is None else max(1, round(about_s))
    shown = "{desc}: {elapsed} so far" if total is None else "{desc}: {bar} {elapsed} of about {total} s"
    bar = tqdm(total=total, desc=desc, unit="s", file=sys.stderr, leave=False, delay=1.0, bar_format=shown)

    def tick() -> None:
        while not done.wait(0.5):
            bar.n = round(time.perf_counter() - start)
            bar.refresh()

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()
        bar.close()
        note(f"{desc}: {time.perf_counter() - start:.1f} s")


@contextlib.contextmanager
def notes_as_lines(command: str):
    """What was done to a recording as it was read (`RecordingNote`: a cut last line dropped, an
    angle unwrapped) printed as one line; any other warning as Python shows it."""
    from manus.plants.errors import RecordingNote

    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message, category, *rest, **kw):
            if issubclass(category, RecordingNote):
                print(f"manus {command}: note: {message}", file=sys.stderr)
            else:
                shown(message, category, *rest, **kw)

        warnings.showwarning = show
        yield
