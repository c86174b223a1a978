"""Exceptions that the CLI turns into one-line errors with exit code 1, and the 'did you mean' hint."""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class LessError(Exception):
    """A runtime or data error with a message fit for one line on stderr.

    The message names the file (or object) and what is wrong, e.g.
    ``scans.npz: 'force' has shape (1000, 48), expected (N, T, 3)``.
    """


class DataError(LessError):
    """An input file is malformed, inconsistent or holds invalid values."""


class SimulationError(LessError):
    """The simulator met a state it cannot model; the message names the sample."""


class HardwareError(LessError):
    """A device (servo bus, camera) failed; the message names port, id and register."""


class TrainingError(LessError):
    """Training cannot continue (e.g. non-finite loss); the message names the step."""


class OutputError(LessError):
    """An output could not be written (full disk, its folder gone, read-only): the message names the
    file; ``path`` is it."""

    def __init__(self, path: str, reason: str) -> None:
        super().__init__(f"{path}: cannot write it ({reason}); nothing was written")
        self.path = path


class BusyError(LessError):
    """Another process is writing the same output (its lock is held)."""


def closest(name: str, choices: Iterable[str]) -> str | None:
    """The valid name closest to ``name``, for 'did you mean' hints (None if nothing is close)."""
    found = difflib.get_close_matches(str(name), sorted(choices), n=1, cutoff=0.5)
    return found[0] if found else None


def did_you_mean(name: str, choices: Iterable[str], otherwise: str = "") -> str:
    """``"; did you mean 'x'?"`` for the closest of ``choices`` to ``name``, else ``otherwise``."""
    found = closest(name, choices)
    return f"; did you mean '{found}'?" if found else otherwise
