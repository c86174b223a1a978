"""Progress for logs: plain lines on stderr where it is not a terminal (a batch job, a cluster log, a pipe).

A terminal gets tqdm's bars (:func:`lesscli.cli.common.progress`); anything else gets :class:`PlainProgress`:
no cursor codes, one line per step of the work that matters to someone reading the log later:

- an epoch bar (``unit="epoch"``): one line per epoch, with what the bar would show after it (the
  training loss, the best validation value);
- any other bar with a known total: one line each time another 10 % is done (and at the end);
- a bar without a total: a line at most every :data:`QUIET_S` seconds, and one at the end.

Each line reads ``less: DESC: N/TOTAL UNIT (P %), 12 s elapsed, ETA 1 min 3 s, key=value``. The object
speaks the part of tqdm's interface the commands use (iteration, ``update``, ``reset``, ``set_postfix``,
``close``, ``with``).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterable
from typing import Self

STEPS = 10                      # lines over a bar with a known total: one per 10 %
QUIET_S = 30.0                  # a bar without a total: at most one line this often


def _duration(seconds: float) -> str:
    """``42 s``, ``3 min 5 s``, ``2 h 4 min``."""
    seconds = max(0.0, seconds)
    if seconds < 60:
        return f"{seconds:.0f} s" if seconds >= 10 else f"{seconds:.1f} s"
    minutes, secs = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {secs} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes} min"


def _amount(n: float, unit_scale: bool, divisor: int) -> str:
    """A count, or with ``unit_scale`` a size with a binary (1024) or decimal prefix: ``12.5 Mi``."""
    if not unit_scale:
        return f"{n:g}" if isinstance(n, float) else str(n)
    prefixes = ("", "K", "M", "G", "T", "P")
    k = 0
    while abs(n) >= divisor and k < len(prefixes) - 1:
        n /= divisor
        k += 1
    suffix = prefixes[k] + ("i" if divisor == 1024 and k else "")
    return f"{n:.1f} {suffix}" if k else f"{n:g} "


class PlainProgress:
    """A tqdm stand-in that writes plain lines to ``file`` (see the module docstring)."""

    def __init__(self, iterable: Iterable | None = None, desc: str | None = None, total: float | None = None,
                 unit: str = "it", initial: float = 0, unit_scale: bool = False, unit_divisor: int = 1000,
                 file=None, clock=time.monotonic, **_ignored) -> None:
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)
        self.iterable, self.desc, self.total, self.unit = iterable, desc or "progress", total, unit
        self.n, self.start_n, self.scale, self.divisor = initial, initial, unit_scale, unit_divisor
        self.file, self.clock = file or sys.stderr, clock
        self.t0 = self.last_line = clock()
        self.postfix: dict = {}
        self.shown_step, self.shown_n = self._step(), None
        self.closed = False

    # -- tqdm's interface ------------------------------------------------------------------------------
    def __iter__(self):
        for item in self.iterable:
            yield item
            self.update(1)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __len__(self) -> int:
        return int(self.total or 0)

    def __bool__(self) -> bool:
        return True

    def update(self, n: float = 1) -> None:
        self.n += n
        if self._due():
            self._line()

    def reset(self, total: float | None = None) -> None:
        self.total, self.n, self.start_n = total, 0, 0
        self.shown_step = 0
        self.t0 = self.last_line = self.clock()

    def set_postfix(self, ordered_dict: dict | None = None, refresh: bool = True, **kwargs) -> None:
        self.postfix = {**(ordered_dict or {}), **kwargs}

    def set_description(self, desc: str, refresh: bool = True) -> None:
        self.desc = desc

    def close(self) -> None:
        if not self.closed and self.n != self.shown_n and self.n > self.start_n:
            self._line()
        self.closed = True

    # -- when and what ---------------------------------------------------------------------------------
    def _step(self) -> int:
        if not self.total:
            return 0
        return math.floor(STEPS * min(self.n, self.total) / self.total + 1e-9)

    def _due(self) -> bool:
        if self.unit == "epoch":
            return True
        if not self.total:
            return self.clock() - self.last_line >= QUIET_S
        return self._step() > self.shown_step

    def _line(self) -> None:
        now = self.clock()
        elapsed = now - self.t0
        done = _amount(self.n, self.scale, self.divisor)
        total = _amount(self.total, self.scale, self.divisor) if self.total else None
        if self.unit == "epoch":
            text = f"epoch {done}" + (f"/{total}" if total else "")
        elif self.scale:                 # sizes: 1.0 MiB/3.0 MiB
            text = f"{done}{self.unit}" + (f"/{total}{self.unit} ({100 * self.n / self.total:.0f} %)"
                                           if total else "")
        else:
            unit = "steps" if self.unit == "it" else (self.unit if self.unit.endswith("s")
                                                      else self.unit + "s")
            text = (f"{done}/{total} {unit} ({100 * self.n / self.total:.0f} %)" if total
                    else f"{done} {unit}")
        text += f", {_duration(elapsed)} elapsed"
        rate_n = self.n - self.start_n
        if self.total and 0 < rate_n and self.n < self.total:
            text += f", ETA {_duration(elapsed / rate_n * (self.total - self.n))}"
        if self.postfix:
            text += ", " + ", ".join(f"{k}={v}" for k, v in self.postfix.items())
        self.file.write(f"less: {self.desc}: {text}\n")
        self.file.flush()
        self.shown_step, self.shown_n, self.last_line = self._step(), self.n, now
