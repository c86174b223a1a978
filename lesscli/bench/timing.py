"""Timing helpers shared by the benchmarks."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager


def best_time(fn: Callable[[], object], repeat: int) -> tuple[float, object]:
    """Best wall time of ``repeat`` calls of ``fn`` (seconds) and the last call's result."""
    best, out = float("inf"), None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - start)
    return best, out


# A busy process: one core's worth of pure-Python spinning, as an ordinary process even when started
# from one under the real-time policy (threads.set_realtime).
SPIN = ("import os\nif hasattr(os, 'sched_setscheduler'):\n    os.sched_setscheduler(0, os.SCHED_OTHER, "
        "os.sched_param(0))\nwhile True:\n    pass\n")


@contextmanager
def busy_processes(n: int, settle_s: float = 0.2) -> Iterator[list[subprocess.Popen]]:
    """``n`` spinning Python processes beside the body, killed and reaped on leaving (errors and Ctrl-C too).

    ``settle_s`` lets them start spinning before the body measures anything.
    """
    procs: list[subprocess.Popen] = []
    try:
        for _ in range(n):
            procs.append(subprocess.Popen([sys.executable, "-c", SPIN], stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        if procs:
            time.sleep(settle_s)
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()
