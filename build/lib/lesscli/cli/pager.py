"""Pager safety: ``less`` installed first on PATH must not break ``git log``, ``man`` or ``less FILE``.

We replace ourselves with the next ``less`` on PATH only when the call is plainly a pager call: no
subcommand and a non-terminal stdin (``git log | less``), or a first argument that is an existing
file (``less README.md``) or a pager option (``less -R``, ``less +G``). Any other first word is a
toolkit command, so a typo (``less simulat``) gets a usage error with the closest subcommand instead
of vanishing into the pager. If there is no system pager, we copy the input (stdin or the named
files) to stdout, as a pager would on a pipe. The ``lesscli`` alias never pages.
"""

from __future__ import annotations

import os
import shutil
import sys

GLOBAL_FLAGS = {"-v", "--verbose", "-vv", "-vvv", "-q", "--quiet", "-h", "--help", "--version"}


def wants_pager(args: list[str], commands: set[str], stdin_is_tty: bool) -> bool:
    """True when the invocation is a pager call (see the module docstring), not a toolkit command."""
    for arg in args:
        if arg in GLOBAL_FLAGS:
            continue
        if arg in commands:
            return False
        return arg.startswith(("-", "+")) or os.path.isfile(arg)
    asked_for_info = any(a in ("-h", "--help", "--version") for a in args)
    return not stdin_is_tty and not asked_for_info


def _is_ours(path: str) -> bool:
    """A ``less`` executable that is this toolkit's console script (any virtual environment)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(2048)
    except OSError:
        return True
    return head.startswith(b"#!") and b"lesscli" in head


def find_system_pager() -> str | None:
    """The first ``less`` on PATH that is not this toolkit's own script."""
    for folder in os.environ.get("PATH", "").split(os.pathsep):
        candidate = os.path.join(folder or ".", "less")
        if os.path.isfile(candidate) and os.access(candidate, os.X_OK) and not _is_ours(candidate):
            return candidate
    return None


def hand_over_to_pager(args: list[str]) -> None:
    """Exec the system pager with ``args``; without one, copy the input to stdout."""
    pager = find_system_pager()
    if pager is not None:
        sys.stdout.flush()
        os.execv(pager, [pager, *args])
    files = [a for a in args if not a.startswith("-") and not a.startswith("+")]
    out = sys.stdout.buffer
    try:
        if not files:
            shutil.copyfileobj(sys.stdin.buffer, out)
        for name in files:
            with open(name, "rb") as fh:
                shutil.copyfileobj(fh, out)
        out.flush()
    except BrokenPipeError:
        pass
    except OSError as exc:
        print(f"less: {exc.filename}: {exc.strerror}", file=sys.stderr)
        sys.exit(1)
