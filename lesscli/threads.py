"""The thread policy: how many CPU threads a command's torch (and BLAS) work gets.

Threads are chosen, not inherited, and the default does not depend on what else the machine is doing,
so the same command gives the same numbers whether it runs alone or beside busy neighbours (the thread
count changes the order of floating-point sums, hence the last bits of every result). Throughput work
takes the usable cores split between ``jobs`` workers, or the user's ``OMP_NUM_THREADS``; latency-bound
work (a stream update, a guide query: real-time, no file whose bits matter) follows the load, one thread
unless the work is large and at least two cores are clearly free; ``--threads N`` fixes the count and
``--threads auto`` asks for the load-adaptive choice for any work (:func:`resolve_threads`).

:func:`set_realtime` (``--realtime`` of ``stream`` and ``bench stream``) lets latency-bound work preempt
other processes instead of waiting out their time slices: the real-time FIFO policy, where permitted.
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
AUTO = "auto"                    # --threads auto: the load-adaptive choice for any work

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
    """The load of the other processes on this machine, read now (see :func:`combined_load`): the average
    alone still counts a job that ended a minute ago, the sample alone misses a bursty one between bursts."""
    return combined_load(load_average(), runnable_now(), starting)


def free_cores(cores: int, load: float) -> int:
    """Usable cores minus the (rounded) load of other processes, at least 1."""
    return max(1, cores - math.floor(load + 0.5))


def choose_threads(cores: int, load: float, work: Work = "throughput", size: float = 0,
                   override: int | None = None, jobs: int = 1) -> int:
    """The load-adaptive rule: threads for each of ``jobs`` workers doing ``work`` of ``size`` flops per
    call, from the free cores (the default for latency-bound work, and ``--threads auto``).

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


def user_threads() -> int | None:
    """The user's ``OMP_NUM_THREADS`` when it was set outside this process (a value this module wrote
    itself does not count) and is a whole number >= 1; None otherwise (a malformed one is logged)."""
    text = os.environ.get("OMP_NUM_THREADS")
    if text is None or not text.strip() or text == _WRITTEN.get("OMP_NUM_THREADS"):
        return None
    try:
        n = int(text.strip())
    except ValueError:
        n = 0
    if n < 1:
        logging.getLogger("less").warning("OMP_NUM_THREADS=%r is not a whole number >= 1; ignored", text)
        return None
    return n


def resolve_threads(work: Work, cores: int, override: int | str | None = None, user: int | None = None,
                    jobs: int = 1, load: Callable[[], float] = lambda: 0.0,
                    size: Callable[[], float] = lambda: 0.0) -> tuple[int, str]:
    """The policy (module docstring): threads for each of ``jobs`` workers, and why, as (count, reason).

    Args:
        work: ``latency`` or ``throughput``.
        cores: usable cores (CPU affinity).
        override: ``--threads``: a count, or :data:`AUTO` for the load-adaptive choice.
        user: the user's ``OMP_NUM_THREADS`` (:func:`user_threads`), or None.
        jobs: worker processes sharing the cores.
        load: the others' load, read only when the choice follows it.
        size: floating-point operations of the dominant call, asked only by latency-bound work.
    """
    if isinstance(override, int):
        return max(1, override), "--threads"
    if override == AUTO or work == "latency":
        others = load()
        n = choose_threads(cores, others, work, size() if work == "latency" else 0, None, jobs)
        why = (f"{'--threads auto' if override == AUTO else 'latency-bound'}: cores {cores}, others' load "
               f"{others:.2f}")
        if user is not None and override != AUTO and n > user:
            return user, f"{why}, capped by OMP_NUM_THREADS"
        return n, why
    if user is not None:
        return user, "OMP_NUM_THREADS"
    return max(1, cores // max(1, jobs)), f"cores {cores}" + (f" / {jobs} workers" if jobs > 1 else "")


def apply_threads(work: Work = "throughput", size: float | Callable[[], float] = 0,
                  override: int | str | None = None, jobs: int = 1, torch_too: bool = True,
                  extra_load: float = 0.0, load: float | None = None) -> int:
    """Choose threads for each of ``jobs`` processes (:func:`resolve_threads`), set them here (before the
    workers fork), and return the count. The machine's load is read only where the choice follows it
    (latency-bound work, ``--threads auto``): ``load`` when the caller has read it already, else now,
    plus ``extra_load`` busy processes started too recently for the 1-minute load to show them. ``size``
    may be a function, called only when the choice needs it; ``torch_too=False`` leaves torch unimported
    (numpy work)."""
    cores = usable_cores()
    read = (lambda: load) if load is not None else (lambda: other_load(extra_load))
    sized = size if callable(size) else (lambda: size)
    n, why = resolve_threads(work, cores, override, user_threads(), jobs, read, sized)
    logging.getLogger("less").info("threads: %d (%s)", n, why)
    set_threads(n, torch_too)
    return n


def parse_threads(text: str | int | None) -> int | str | None:
    """``--threads`` text: a whole number >= 1 or ``auto`` (ValueError otherwise); None stays None."""
    if text is None or isinstance(text, int):
        return text
    if text.strip().lower() == AUTO:
        return AUTO
    n = int(text)
    if n < 1:
        raise ValueError(text)
    return n


# Read by BLAS/OpenMP libraries when they load: scipy bundles its own OpenBLAS, loaded on first use,
# after the limit below has been applied to the pools already loaded. OpenBLAS and MKL read their own
# variable before OMP_NUM_THREADS, so a user's OMP_NUM_THREADS can stay as it is.
POOL_ENV_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
_WRITTEN: dict[str, str] = {}    # the values this module put into the environment


def set_threads(n: int, torch_too: bool = True) -> None:
    """Set torch's intra-op threads (``torch_too``) and, where threadpoolctl is installed, the BLAS/OpenMP
    pools (forked workers inherit both); pools loaded later start with ``n`` threads from the environment.
    A variable the user set is left as it is."""
    for name in POOL_ENV_VARS:
        if name not in os.environ or os.environ[name] == _WRITTEN.get(name):
            os.environ[name] = _WRITTEN[name] = str(n)
    if torch_too:
        import torch

        torch.set_num_threads(n)
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:          # optional: torch's own pools are set either way
        pass
    else:
        threadpool_limits(n)


def deterministic_kernels(device) -> None:
    """Torch's deterministic kernels where the work runs on the CPU. With several threads some kernels
    otherwise add in the order the threads finish: a sum into indexed rows (``index_put_`` with
    ``accumulate``, the backward of ``x[index]``) gave weights that differed in the last bits from one
    run to the next. On a GPU the choice is left to torch (its deterministic kernels are slower there,
    and some have none)."""
    import torch

    if torch.device(device).type == "cpu":
        torch.use_deterministic_algorithms(True, warn_only=True)


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
