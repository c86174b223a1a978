"""Atomic outputs: write to a temporary sibling, rename on success, remove on failure.

A failed or interrupted command therefore never leaves a partial file. ``-`` means stdout for
binary outputs, which are refused when stdout is a terminal.
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


def _tmp_sibling(path: str, suffix: str) -> str:
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise LessError(f"{path}: folder '{folder}' does not exist")
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
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_dir(path: str) -> Iterator[str]:
    """Yield a temporary folder; on success its files move into ``path`` (created if needed)."""
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise LessError(f"{path}: folder '{parent}' does not exist")
    tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(os.path.abspath(path))}.", suffix=".part", dir=parent)
    try:
        yield tmp
        if not os.path.exists(path):
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
