"""Exceptions that the CLI turns into one-line errors with exit code 1."""


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
