"""The thread policy: how many CPU threads a command's torch (and BLAS) work gets.

Threads are chosen, not inherited. Threads that wait on each other collapse when the cores are
shared, so the count follows the cores actually free when the command starts: the cores this process
may run on minus the load of everything else, at least one. That load is the smaller of the 1-minute
load average and the processes runnable right now (a short sample): the average alone still counts a
job that ended a minute ago, the sample alone misses a bursty one between its bursts.

- Latency-bound work (a stream update, a guide query) runs on one thread, unless
  the work is large and at least two cores are clearly free.
- Throughput work (training, benchmarks of it) uses every free core.
- ``jobs`` worker processes split the free cores between them (at least one each).
- ``--threads N`` overrides the choice.

:func:`choose_threads` is the pure rule (table-tested); :func:`apply_threads` reads the machine,
applies the choice to torch and, where threadpoolctl is installed, to the BLAS/OpenMP pools.

Fewer threads keep latency-bound work from waiting on its own threads, not on other processes: with
more runnable processes than cores, an update now and then waits out another's time slice.
:func:`set_realtime` (``--realtime`` of ``stream`` and ``bench stream``) lets it preempt them instead:
the real-time FIFO policy, where the system permits it.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable
from typing import Literal

from lesscli.errors import LessError

Work = Literal["latency", "throughput"]

# Floating-point operations per call above which a latency-bound call gains from a thread pool: a few
# ms of one core. Below it the cost of waking and joining threads is of the order of the work itself.
LARGE_WORK = 100_000_000
CLEARLY_FREE = 2                 # free cores needed before latency-bound work takes more than one


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:       # no affinity on this platform
        return os.cpu_count() or 1


LOAD_SAMPLES = 8                 # instantaneous runnable counts averaged by ``runnable_now``
SAMPLE_GAP_S = 0.004             # between samples (the sample costs ~30 ms once per command)


def load_average() -> float:
    """The 1-minute load average (0 where the platform has none)."""
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):
        return 0.0


def runnable_now(path: str = "/proc/loadavg", own_tasks: str = "/proc/self/task") -> float | None:
    """Other processes' threads runnable right now: the mean over a short sample of the kernel's runnable
    count (4th field of ``/proc/loadavg``, ``running/total``) less this process's own running threads
    (``own_tasks``; a thread pool still spinning after its last job is runnable too, and at least the
    thread reading); None where there is no such file."""
    counts = []
    for i in range(LOAD_SAMPLES):
        try:
            with open(path) as f:
                running = int(f.read().split()[3].split("/")[0])
        except (OSError, IndexError, ValueError):
            return None
        counts.append(running - max(1, _own_running(own_tasks)))
        if i + 1 < LOAD_SAMPLES:
            time.sleep(SAMPLE_GAP_S)
    return max(0.0, sum(counts) / len(counts))


def _own_running(own_tasks: str) -> int:
    """Threads of this process in state R (0 where the task folder cannot be read)."""
    try:
        tids = os.listdir(own_tasks)
    except OSError:
        return 0
    n = 0
    for tid in tids:
        try:
            with open(os.path.join(own_tasks, tid, "stat")) as f:
                n += f.read().rsplit(")", 1)[1].split()[0] == "R"
        except (OSError, IndexError):
            continue
    return n


def combined_load(average: float, now: float | None, starting: float = 0.0) -> float:
    """The others' load: the smaller of the 1-minute average (plus ``starting`` busy processes too new
    for it to show) and the runnable sample, which sees those already; the average alone without one."""
    if now is None:
        return average + starting
    return min(average + starting, now)


def other_load(starting: float = 0.0) -> float:
    """The load of the other processes on this machine, read now (see :func:`combined_load`)."""
    return combined_load(load_average(), runnable_now(), starting)


def free_cores(cores: int, load: float) -> int:
    """Usable cores minus the (rounded) load of other processes, at least 1."""
    return max(1, cores - math.floor(load + 0.5))


def choose_threads(cores: int, load: float, work: Work = "throughput", size: float = 0,
                   override: int | None = None, jobs: int = 1) -> int:
    """Threads for each of ``jobs`` workers doing ``work`` of ``size`` flops per call.

    Args:
        cores: usable cores (CPU affinity).
        load: load of the other processes (:func:`other_load`).
        work: ``latency`` (one small call at a time) or ``throughput`` (training, benchmarks).
        size: floating-point operations of the dominant call (only latency work looks at it).
        override: ``--threads``; wins when given.
        jobs: worker processes sharing the free cores.
    """
    if override is not None:
        return max(1, override)
    share = max(1, free_cores(cores, load) // max(1, jobs))
    if work == "latency" and not (share >= CLEARLY_FREE and size >= LARGE_WORK):
        return 1
    return share


def apply_threads(work: Work = "throughput", size: float | Callable[[], float] = 0, override: int | None = None,
                  jobs: int = 1, torch_too: bool = True, extra_load: float = 0.0, load: float | None = None) -> int:
    """Choose threads for each of ``jobs`` processes from the machine's free cores, set them here (before
    the workers fork), and return the count. ``size`` may be a function, called only when the choice
    needs it (not with ``override``); ``torch_too=False`` leaves torch unimported (numpy work);
    ``extra_load`` counts busy processes started too recently for the 1-minute load to show them; ``load``
    is the others' load when the caller has read it already (the machine is read once, and not at all
    with ``override``)."""
    log = logging.getLogger("less")
    if override is not None:
        n = choose_threads(usable_cores(), 0.0, work, 0, override, jobs)
        log.info("threads: %d (--threads)", n)
    else:
        load = other_load(extra_load) if load is None else load
        n = choose_threads(usable_cores(), load, work, size() if callable(size) else size, None, jobs)
        log.info("threads: %d (cores %d, others' load %.2f)", n, usable_cores(), load)
    set_threads(n, torch_too)
    return n


# Read by BLAS/OpenMP libraries when they load: scipy bundles its own OpenBLAS, loaded on first use,
# after the limit below has been applied to the pools already loaded.
POOL_ENV_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def set_threads(n: int, torch_too: bool = True) -> None:
    """Set torch's intra-op threads (``torch_too``) and, where threadpoolctl is installed, the BLAS/OpenMP
    pools (forked workers inherit both); pools loaded later start with ``n`` threads from the environment."""
    for name in POOL_ENV_VARS:
        os.environ[name] = str(n)
    if torch_too:
        import torch

        torch.set_num_threads(n)
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:          # optional: torch's own pools are set either way
        pass
    else:
        threadpool_limits(n)


REALTIME_PRIORITY = 10           # SCHED_FIFO priority of --realtime (1-99): above every normal process, low among RT


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
                            f"root, CAP_SYS_NICE or a real-time limit `ulimit -r` of {priority} or more)") from None
    logging.getLogger("less").info("scheduling: real-time FIFO, priority %d", priority)
