"""Real-time scheduling for the hardware loop's thread (Linux): `SCHED_FIFO` and memory locked.

Under `SCHED_FIFO` the loop's thread runs before every ordinary process the moment its sample
arrives (another program busy on the same cores waits for it), and its memory stays resident
(`mlockall`, each page locked as it is first touched: JAX's large reserved mappings are not
forced into memory). A real-time thread must wait by blocking (a timed `select` on the device's
socket), never by spinning: the kernel stops a real-time task that does not sleep for 50 ms of
each second (`/proc/sys/kernel/sched_rt_runtime_us`), and the device's watchdog fires. The
scheduling applies to the calling thread only: JAX's worker threads keep theirs, and a thread or
process started while it runs (a worker JAX starts late) starts as an ordinary one
(`SCHED_RESET_ON_FORK`): a real-time worker that spins while it waits would hold a core from
everything else. `Realtime` restores the thread's scheduling when the run ends. Where it is
refused (no root, no `CAP_SYS_NICE`, not Linux), the loop runs as an ordinary process and says
why."""

from __future__ import annotations

import ctypes
import os
import sys

PRIORITY = 80  # SCHED_FIFO priority of the loop (the emulator playing the rig takes one less)
MCL_CURRENT, MCL_FUTURE, MCL_ONFAULT = 1, 2, 4


class Realtime:
    """`with Realtime(priority) as rt:` the calling thread under SCHED_FIFO with its memory locked,
    if allowed; `rt.active` says whether it is, `rt.why` what was done or refused."""

    def __init__(self, priority: int = PRIORITY):
        self.priority, self.active, self.locked, self.why = priority, False, False, ""
        self._before: tuple[int, int] | None = None

    def __enter__(self) -> Realtime:
        if not sys.platform.startswith("linux") or not hasattr(os, "sched_setscheduler"):
            self.why = "real-time scheduling is Linux's (SCHED_FIFO): an ordinary process here"
            return self
        try:
            self._before = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
            # (threads and processes started from it, JAX's workers among them, start as ordinary ones)
            os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(self.priority))
        except OSError as e:
            self.why = (
                f"SCHED_FIFO refused ({e.strerror}): an ordinary process, which other work on these "
                "cores can delay (run as root, or give python CAP_SYS_NICE)"
            )
            return self
        self.active = True
        libc = ctypes.CDLL(None, use_errno=True)
        self.locked = libc.mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) == 0
        memory = "memory locked" if self.locked else f"memory not locked ({os.strerror(ctypes.get_errno())})"
        self.why = f"SCHED_FIFO priority {self.priority}, {memory}"
        return self

    def __exit__(self, *exc) -> None:
        if self.locked:
            ctypes.CDLL(None).munlockall()
        if self.active and self._before is not None:
            policy, priority = self._before
            os.sched_setscheduler(0, policy, os.sched_param(priority))
        self.active = self.locked = False
