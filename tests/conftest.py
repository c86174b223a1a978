import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent


def popen_interruptible(args, **kwargs) -> subprocess.Popen:
    """``subprocess.Popen(args)`` with SIGINT caught (not ignored) here while the child starts: a suite
    started in the background (`make test &`) ignores SIGINT and a child inherits an ignored signal,
    while a handled one is reset to the default at exec, as a terminal's foreground job has it."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return subprocess.Popen(args, **kwargs)
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.fixture
def run_less(tmp_path):
    """Run the installed ``less`` console script in a subprocess (real pipes, real exit codes)."""

    def run(*args, input=None, check=False, cwd=None, env=None):
        full_env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", **(env or {})}
        proc = subprocess.run([str(BIN / "less"), *map(str, args)], input=input, capture_output=True,
                              cwd=cwd or tmp_path, env=full_env, timeout=600, check=False)
        if check and proc.returncode != 0:
            raise AssertionError(f"less {' '.join(map(str, args))} failed ({proc.returncode}):\n"
                                 f"{proc.stderr.decode(errors='replace')}")
        return proc

    return run


@pytest.fixture
def scanset_file(tmp_path):
    """A small valid scan set on disk."""
    from factories import random_scanset

    from lesscli.io.scans import save_scans

    path = tmp_path / "scans.npz"
    save_scans(str(path), random_scanset())
    return path
