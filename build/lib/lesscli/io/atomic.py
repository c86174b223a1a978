"""Atomic outputs: write to a temporary sibling, rename on success, remove on failure.

A failed or interrupted command therefore never leaves a partial file. ``-`` means stdout for
binary outputs, which are refused when stdout is a terminal. A finished output gets the mode a plain
``open()`` / ``mkdir`` would give it (0666 / 0777 less the umask: 0644 / 0755 under umask 022), not
the private mode of the temporary file. :func:`check_output` tests an output path before any work
starts, so a typo in ``-o`` fails at once and not after an hour of training.
"""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator

from lesscli.errors import LessError


def _umask() -> int:
    """The process umask, read without changing it where the system tells it (Linux), else set back."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def publish_mode(path: str) -> None:
    """Give ``path`` the mode ``open()`` (a file) or ``mkdir`` (a folder) would under the current umask."""
    os.chmod(path, (0o777 if os.path.isdir(path) else 0o666) & ~_umask())


def check_output(path: str, folder: bool = False, option: str = "-o") -> None:
    """Raise LessError unless ``path`` can be written: its folder exists and is writable, and it is
    not a folder (for a file output) or a file (for a folder output). ``-`` (stdout) passes for files.
    """
    if path == "-":
        if folder:
            raise LessError(f"{option} -: this output is a folder and cannot go to stdout; name a folder")
        return
    if not path:
        raise LessError(f"{option}: empty output path")
    parent = os.path.dirname(os.path.abspath(path))
    if folder and os.path.exists(path) and not os.path.isdir(path):
        raise LessError(f"{path}: is a file, but {option} names an output folder here; choose a folder name")
    if not folder and os.path.isdir(path):
        raise LessError(f"{path}: is a folder, but {option} names an output file here; name a file inside it")
    if not os.path.isdir(parent):
        raise LessError(f"{path}: folder '{parent}' does not exist; create it first (mkdir -p)")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise LessError(f"{path}: folder '{parent}' is not writable")


def _tmp_sibling(path: str, suffix: str) -> str:
    check_output(path)
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".part" + suffix, dir=folder)
    os.close(fd)
    return tmp


@contextlib.contextmanager
def atomic_path(path: str, suffix: str = "") -> Iterator[str]:
    """Yield a temporary path to write; it becomes ``path`` only if the block succeeds.

    Args:
        path: final output path, or ``-`` for stdout (binary; refused on a terminal).
        suffix: extension the writer needs to see on the temporary file (e.g. ``.npz``, ``.nii.gz``).
    """
    if path == "-":
        if sys.stdout.isatty():
            raise LessError("refusing to write binary output to a terminal; use -o FILE or a pipe")
        tmpdir = tempfile.mkdtemp(prefix="less-")
        tmp = os.path.join(tmpdir, "out" + suffix)
        try:
            yield tmp
            sys.stdout.flush()
            with open(tmp, "rb") as fh:
                shutil.copyfileobj(fh, sys.stdout.buffer)
            sys.stdout.buffer.flush()
        finally:
            shutil.rmtree(tmpdir, ignore_errors=True)
        return
    tmp = _tmp_sibling(path, suffix)
    try:
        yield tmp
        publish_mode(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_dir(path: str) -> Iterator[str]:
    """Yield a temporary folder; on success its files move into ``path`` (created if needed)."""
    check_output(path, folder=True)
    parent = os.path.dirname(os.path.abspath(path))
    tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(os.path.abspath(path))}.", suffix=".part", dir=parent)
    try:
        yield tmp
        if not os.path.exists(path):
            publish_mode(tmp)
            os.replace(tmp, path)
            return
        for root, _dirs, files in os.walk(tmp):
            rel = os.path.relpath(root, tmp)
            os.makedirs(os.path.join(path, rel), exist_ok=True)
            for name in files:
                os.replace(os.path.join(root, name), os.path.join(path, rel, name))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def open_input_bytes(path: str) -> io.BytesIO | str:
    """``-`` -> stdin read into memory (seekable, as np.load needs); otherwise the path itself."""
    if path == "-":
        return io.BytesIO(sys.stdin.buffer.read())
    if not os.path.exists(path):
        raise LessError(f"{path}: no such file")
    return path
