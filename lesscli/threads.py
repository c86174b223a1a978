"""The thread policy: how many CPU threads a command's torch (and BLAS) work gets.

Threads are chosen, not inherited, from the usable cores and the 1-minute load average only. Throughput
work (training, prediction, simulation, benchmarks) takes the cores split between ``jobs`` workers, or
the user's ``OMP_NUM_THREADS``, whatever the load: the thread count changes the order of floating-point
sums, so the same command gives the same bits alone or beside busy neighbours. Latency-bound work (a
stream update, a guide query: real time, no file whose bits matter) takes two threads where the load
leaves two cores free, else one: two beside a busy neighbour wait on each other's time slices.
``--threads N`` fixes the count; ``--threads auto`` takes the free cores for any work.
"""

from __future__ import annotations

import logging
import math
import os
from typing import Literal

Work = Literal["latency", "throughput"]
AUTO = "auto"                    # --threads auto: the free cores, for any work
LATENCY_MAX = 2                  # most threads a latency-bound call takes by default


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def load_average() -> float:
    """The 1-minute load average (0 where the platform has none)."""
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):
        return 0.0


def free_cores(cores: int, load: float) -> int:
    """Usable cores minus the (rounded) load of other processes, at least 1."""
    return max(1, cores - math.floor(load + 0.5))


def resolve_threads(work: Work, cores: int, override: int | str | None = None, user: int | None = None,
                    jobs: int = 1, load: float = 0.0) -> tuple[int, str]:
    """Threads for each of ``jobs`` workers doing ``work`` (module docstring), and why: ``override`` is
    ``--threads`` (a count or :data:`AUTO`), ``user`` the user's ``OMP_NUM_THREADS``, ``load`` the
    others' load (read by the choices that follow it)."""
    if isinstance(override, int):
        return max(1, override), "--threads"
    share = max(1, free_cores(cores, load) // max(1, jobs))
    if override == AUTO:
        return share, f"--threads auto: cores {cores}, load {load:.2f}"
    if work == "latency":
        n = min(LATENCY_MAX, share)
        why = f"latency-bound: cores {cores}, load {load:.2f}"
        return (user, f"{why}, capped by OMP_NUM_THREADS") if user is not None and n > user else (n, why)
    if user is not None:
        return user, "OMP_NUM_THREADS"
    return max(1, cores // max(1, jobs)), f"cores {cores}" + (f" / {jobs} workers" if jobs > 1 else "")


def apply_threads(work: Work = "throughput", override: int | str | None = None, jobs: int = 1,
                  torch_too: bool = True, load: float | None = None) -> int:
    """Choose threads for each of ``jobs`` processes (:func:`resolve_threads`), set them here (before the
    workers fork) and return the count. ``load``: the others' load where the caller knows better than the
    load average (busy processes it just started); ``torch_too=False`` leaves torch unimported."""
    others = load_average() if load is None else load
    n, why = resolve_threads(work, usable_cores(), override, user_threads(), jobs, others)
    logging.getLogger("less").info("threads: %d (%s)", n, why)
    set_threads(n, torch_too)
    return n


def user_threads() -> int | None:
    """The user's ``OMP_NUM_THREADS`` when it was set outside this process (a value this module wrote
    itself does not count) and is a whole number >= 1; None otherwise (a malformed one is logged)."""
    text = os.environ.get("OMP_NUM_THREADS")
    if text is None or not text.strip() or text == _WRITTEN.get("OMP_NUM_THREADS"):
        return None
    n = int(text) if text.strip().isdigit() else 0
    if n < 1:
        logging.getLogger("less").warning("OMP_NUM_THREADS=%r is not a whole number >= 1; ignored", text)
        return None
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


# Read by BLAS/OpenMP pools as they load (scipy's own OpenBLAS loads on first use, after set_threads);
# OpenBLAS and MKL read their own variable first, so a user's OMP_NUM_THREADS can stay as it is.
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
        return
    threadpool_limits(n)


def deterministic_kernels(device) -> None:
    """Torch's deterministic kernels on the CPU: with several threads a sum into indexed rows (the
    backward of ``x[index]``) otherwise adds in the order the threads finish. A GPU is left to torch."""
    import torch

    if torch.device(device).type == "cpu":
        torch.use_deterministic_algorithms(True, warn_only=True)
