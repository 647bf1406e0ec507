"""Figures drawn beside the analysis (manus.runs.figures.worker): what the worker draws is, pixel for
pixel, what this process draws; a worker that dies leaves its figures drawn here; a few panels are
drawn at once, without a worker."""

import os
import signal
import time

import numpy as np
import pytest
from matplotlib.image import imread

from manus.runs.figures import worker
from manus.runs.figures.diagnose import diagnosis_figures
from manus.runs.figures.worker import WORKER_PANELS, Painter


@pytest.fixture(scope="module")
def diagnosis():
    """A 2-joint recording with an offset hidden, diagnosed (its candidates fitted, a verdict)."""
    from manus.adaptive import diagnose
    from manus.experiments import calibration

    c = calibration.case(0, "offset", rates=(200,))
    return diagnose(c.rec, c.start)


def _paths(figures: dict) -> list[str]:
    return [
        figures["resid"],
        *figures["evidence"].values(),
        *([figures["unexplained"]] if figures["unexplained"] else []),
    ]


def test_the_worker_draws_what_this_process_draws(diagnosis, tmp_path):
    here = diagnosis_figures(diagnosis, tmp_path / "here", "d", Painter(0))
    painter = Painter(WORKER_PANELS)
    assert painter.remote
    there = diagnosis_figures(diagnosis, tmp_path / "there", "d", painter)
    assert (
        list(there["evidence"])
        == list(here["evidence"])
        == [c.effect for c in diagnosis.candidates if c.fit is not None or c.mode is not None]
    )
    assert len(here["evidence"]) >= 6
    for a, b in zip(_paths(here), _paths(there), strict=True):
        assert os.path.basename(a) == os.path.basename(b) and "/there/" in b
        np.testing.assert_array_equal(imread(a), imread(b))


def test_a_dead_worker_leaves_its_figures_drawn_here(diagnosis, tmp_path):
    painter = Painter(WORKER_PANELS)
    painter.draw(int, "1").result()  # the worker is up
    for pid in list(worker._pool()._processes):  # killed as an out-of-memory killer would
        os.kill(pid, signal.SIGKILL)
    figures = diagnosis_figures(diagnosis, tmp_path, "d", painter)
    assert all(os.path.getsize(p) > 10_000 for p in _paths(figures))
    assert Painter(WORKER_PANELS).draw(int, "2").result() == 2  # the next one starts a new worker


def test_few_panels_are_drawn_at_once_here():
    if worker._pool.cache_info().currsize:  # (no worker up: an earlier test's stopped)
        worker._pool().shutdown()
        worker._pool.cache_clear()
    painter = Painter(WORKER_PANELS - 1)
    assert not painter.remote
    job = painter.draw(os.getpid)
    assert job.result() == os.getpid()  # drawn in this process, before `draw` returned


FORKED = """
import sys
import numpy as np
from matplotlib.image import imread
from manus.runs.figures import worker
from manus.runs.figures.worker import WORKER_PANELS, Painter
painter = Painter(WORKER_PANELS)  # (as a command asks: before JAX runs anything)
assert worker._pool()._mp_context.get_start_method() == "fork"
from manus.adaptive import diagnose
from manus.experiments import calibration
from manus.runs.figures.diagnose import diagnosis_figures
c = calibration.case(0, "offset", rates=(200,))
d = diagnose(c.rec, c.start)
there = diagnosis_figures(d, sys.argv[1] + "/there", "d", painter)
here = diagnosis_figures(d, sys.argv[1] + "/here", "d", Painter(0))
assert len(here["evidence"]) >= 6
for a, b in zip([here["resid"], *here["evidence"].values()], [there["resid"], *there["evidence"].values()]):
    assert "/there/" in b
    np.testing.assert_array_equal(imread(a), imread(b))
print("same")
"""


def test_a_worker_forked_before_jax_runs_draws_what_this_process_draws(tmp_path):
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", FORKED, str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "same"


def test_a_worker_already_up_draws_few_panels_too():
    Painter(WORKER_PANELS).draw(int, "1").result()  # (as a command expecting a large figure set starts it)
    painter = Painter(1)
    assert painter.remote
    job = painter.draw(os.getpid)
    future = job._future  # (the worker takes it: a job not yet taken when asked for is drawn here)
    assert future is not None
    while not (future.running() or future.done()):
        time.sleep(0.01)
    assert job.result() != os.getpid()


def test_a_job_the_worker_has_not_started_is_drawn_here(tmp_path):
    import subprocess
    import threading

    go = tmp_path / "go"
    painter = Painter(WORKER_PANELS)
    # the worker busy until `go` exists; it takes at most three jobs at once (one running, two in its
    # queue): the job after `busy` is one of them, the third after it never is while `busy` runs
    busy = painter.draw(subprocess.run, ["sh", "-c", f"while [ ! -e {go} ]; do sleep 0.05; done"])
    taken = painter.draw(os.getpid)
    either = painter.draw(os.getpid)
    last = painter.draw(os.getpid)
    queued = taken._future
    assert queued is not None
    while not (queued.running() or queued.done()):  # (in the worker's queue once the executor's thread moves it)
        time.sleep(0.01)
    late = threading.Timer(60, go.touch)  # (a result that waited for the worker would come, from it, then)
    late.start()
    assert last.result() == os.getpid()  # not started: drawn here, without waiting for the worker
    late.cancel()
    go.touch()
    assert busy.result().returncode == 0
    assert taken.result() != os.getpid()
    assert either.result() > 0  # (drawn by whichever was free)
