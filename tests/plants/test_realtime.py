"""Real-time scheduling of the loop's thread (`manus.plants.realtime`): what it changes, what it
leaves as it was, and what a refusal says."""

import os
import threading

import pytest

from manus.plants.realtime import PRIORITY, Realtime


def test_only_the_calling_thread_runs_in_real_time_and_only_while_asked():
    """Inside: the thread under SCHED_FIFO at `PRIORITY`; a thread started from it (a worker JAX
    starts late) is an ordinary one; after: the thread's scheduling as it was."""
    before = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    with Realtime() as rt:
        if not rt.active:
            pytest.skip(f"this machine refuses real-time scheduling: {rt.why}")
        assert os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK == os.SCHED_FIFO
        assert os.sched_getparam(0).sched_priority == PRIORITY
        started = {}
        worker = threading.Thread(target=lambda: started.update(policy=os.sched_getscheduler(0)))
        worker.start()
        worker.join()
        assert started["policy"] == os.SCHED_OTHER
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before


def test_real_time_refused_is_said_and_changes_nothing(monkeypatch):
    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with Realtime() as rt:
        assert not rt.active and not rt.locked
        assert rt.why.startswith("SCHED_FIFO refused (Operation not permitted)")
