"""Shared CLI plumbing: verbosity, logging, progress bars, common options, name suggestions."""

from __future__ import annotations

import difflib
import logging
import sys
from collections.abc import Iterable
from dataclasses import dataclass

import click

LOG = logging.getLogger("less")


@dataclass
class _State:
    verbose: int = 0
    quiet: bool = False


STATE = _State()


def configure(verbose: int = 0, quiet: bool = False) -> None:
    """Set up stderr logging for this process from ``-v``/``-q``."""
    STATE.verbose, STATE.quiet = verbose, quiet
    level = logging.ERROR if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    if verbose == 0 and not quiet:
        level = logging.WARNING
    for old in list(LOG.handlers):  # in-process reruns (tests) must log to the current stderr
        LOG.removeHandler(old)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("less: %(message)s"))
    LOG.addHandler(handler)
    LOG.propagate = False
    LOG.setLevel(level)


def progress(iterable: Iterable | None = None, **kwargs):
    """A tqdm progress bar on stderr, silent with ``-q`` (and when stderr is not a terminal and -v is off)."""
    from tqdm import tqdm

    disable = STATE.quiet or (not sys.stderr.isatty() and STATE.verbose == 0)
    return tqdm(iterable, file=sys.stderr, disable=disable, dynamic_ncols=True, **kwargs)


def closest(name: str, choices: Iterable[str]) -> str | None:
    """The closest valid name to ``name``, for 'did you mean' hints (None if nothing is close)."""
    found = difflib.get_close_matches(name, list(choices), n=1, cutoff=0.5)
    return found[0] if found else None


def format_option(func):
    """``--format jsonl|json|table|markdown`` (default: table on a terminal, JSON lines otherwise)."""
    return click.option(
        "--format",
        "fmt",
        type=click.Choice(["jsonl", "json", "table", "markdown"]),
        default=None,
        help="Record format on stdout (default: table on a terminal, else JSON lines).",
    )(func)


def output_option(required: bool = True, help: str = "Output file ('-' for stdout)."):
    """``-o/--output PATH``."""
    return click.option("-o", "--output", "output", type=str, required=required, help=help)


def seed_option(default: int = 0):
    return click.option("--seed", type=int, default=default, show_default=True, help="Random seed.")


def parse_shard(text: str | None) -> tuple[int, int]:
    """Parse ``i/n`` (0-based shard i of n); None means the whole job (0/1)."""
    if not text:
        return 0, 1
    try:
        i, n = (int(p) for p in text.split("/"))
    except ValueError:
        raise click.BadParameter(f"'{text}' is not of the form i/n (e.g. 0/4)", param_hint="--shard")
    if n < 1 or not 0 <= i < n:
        raise click.BadParameter(f"'{text}': need 0 <= i < n", param_hint="--shard")
    return i, n
