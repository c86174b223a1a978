"""``--realtime`` of ``stream`` and ``bench stream``: latency-bound work preempts other processes instead
of waiting out their time slices, under the real-time FIFO scheduling policy where it is permitted."""

from __future__ import annotations

import logging
import os

from lesscli.errors import LessError

# SCHED_FIFO priority of --realtime (1-99): above every normal process, low among RT
REALTIME_PRIORITY = 10


def set_realtime(priority: int = REALTIME_PRIORITY, tasks: str = "/proc/self/task") -> None:
    """Run every thread of this process, and those it starts later, under the real-time FIFO policy
    at ``priority``: each preempts normal processes at once instead of sharing a core with them.

    A thread that does not block holds its core until it does (the kernel keeps 5 % of each second
    for the others by default), so it suits latency-bound work paced by its input. Processes started
    from here inherit the policy unless they reset it (the busy processes of the benchmarks do).
    Raises LessError where the platform has no such policy or the process may not take it.
    """
    if not hasattr(os, "SCHED_FIFO"):
        raise LessError("--realtime: this platform has no real-time scheduling (SCHED_FIFO, Linux)")
    try:
        tids = [int(t) for t in os.listdir(tasks)]
    except OSError:
        tids = [0]
    for tid in tids:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
        except ProcessLookupError:   # a thread that ended meanwhile
            continue
        except PermissionError:
            raise LessError(f"--realtime: this process may not take real-time priority {priority} (it needs "
                            f"root, CAP_SYS_NICE or a real-time limit `ulimit -r` of {priority} or "
                            "more)") from None
    logging.getLogger("less").info("scheduling: real-time FIFO, priority %d", priority)
