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
# from one under the real-time policy (realtime.set_realtime).
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


class PeakMemory:
    """What :func:`peak_memory` measured: ``mb``, the peak resident memory over its body (None where
    the peak cannot be reset)."""

    mb: float | None = None


def _reset_peak() -> bool:
    try:                                   # Linux: writing 5 resets the process's peak RSS (VmHWM)
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _peak_mb() -> float | None:
    try:
        with open("/proc/self/status") as f:
            line = next(x for x in f if x.startswith("VmHWM:"))
    except (OSError, StopIteration):
        return None
    return int(line.split()[1]) / 1024.0


@contextmanager
def peak_memory() -> Iterator[PeakMemory]:
    """The peak resident memory of this process (MB) over the body, in ``.mb`` on leaving: what the
    stage needed on top of what the process already held, plus that. None off Linux."""
    out = PeakMemory()
    ok = _reset_peak()
    try:
        yield out
    finally:
        out.mb = _peak_mb() if ok else None
