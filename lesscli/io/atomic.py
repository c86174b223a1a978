"""Atomic outputs: write to a temporary sibling, rename on success, remove on failure.

A failed or interrupted command therefore never leaves a partial file. ``-`` means stdout for
binary outputs, which are refused when stdout is a terminal. A finished output gets the mode a plain
``open()`` / ``mkdir`` would give it (0666 / 0777 less the umask: 0644 / 0755 under umask 022), not
the private mode of the temporary file. :func:`check_output` tests an output path before any work
starts, so a typo in ``-o`` fails at once and not after an hour of training.

A write that fails (a full disk, a quota, the output's folder removed meanwhile) is one
:class:`~lesscli.errors.OutputError` naming the output, with the temporary file removed. A command
that runs long holds :func:`output_lock` on its output (``OUT.lock`` beside it), so that a second run
writing the same output refuses at its start instead of interleaving with the first.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator

from lesscli.errors import BusyError, LessError, OutputError


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


# errors of the device or the filesystem, whatever file they name: the output is what failed
WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO}


def write_failure(exc: BaseException, path: str, *ours: str) -> OutputError | None:
    """The one-line error for ``exc`` when it is a failure to write ``path`` (through the temporary files
    ``ours``): a full disk or quota, a read-only or failing device, or an error on a file of ours or
    none named (a write or close on an open file; its folder removed meanwhile); else None."""
    if not isinstance(exc, OSError) or isinstance(exc, (BrokenPipeError, InterruptedError)):
        return None
    names = {path, *ours}
    if exc.errno in WRITE_ERRNOS or exc.filename is None or exc.filename in names or \
            any(str(exc.filename).startswith(o + os.sep) for o in ours):
        return OutputError(path, exc.strerror or str(exc))
    return None


def _tmp_sibling(path: str, suffix: str) -> str:
    check_output(path)
    folder = os.path.dirname(os.path.abspath(path))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.", suffix=".part" + suffix, dir=folder)
    except OSError as exc:
        raise (write_failure(exc, path, folder) or exc) from None
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
        _publish_or_defer(path, lambda: _publish_file(tmp, path), lambda: _remove(tmp), (tmp,))
    except BaseException as exc:
        _remove(tmp)
        failure = write_failure(exc, path, tmp)
        if failure is not None:
            raise failure from None
        raise


@contextlib.contextmanager
def atomic_dir(path: str) -> Iterator[str]:
    """Yield a temporary folder; on success its files move into ``path`` (created if needed)."""
    check_output(path, folder=True)
    parent = os.path.dirname(os.path.abspath(path))
    try:
        tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(os.path.abspath(path))}.", suffix=".part",
                               dir=parent)
    except OSError as exc:
        raise (write_failure(exc, path, parent) or exc) from None
    deferred = False
    try:
        yield tmp
        deferred = _publish_or_defer(path, lambda: _publish_dir(tmp, path),
                                     lambda: shutil.rmtree(tmp, ignore_errors=True),
                                     (tmp, os.path.abspath(path)))
    except BaseException as exc:
        failure = write_failure(exc, path, tmp, os.path.abspath(path))
        if failure is not None:
            raise failure from None
        raise
    finally:
        if not deferred:
            shutil.rmtree(tmp, ignore_errors=True)


def _remove(tmp: str) -> None:
    with contextlib.suppress(OSError):
        os.unlink(tmp)


def _publish_file(tmp: str, path: str) -> None:
    publish_mode(tmp)
    os.replace(tmp, path)


def _publish_dir(tmp: str, path: str) -> None:
    """Move the finished folder ``tmp`` to ``path``, or its files into ``path`` where that folder exists."""
    if not os.path.exists(path):
        publish_mode(tmp)
        os.replace(tmp, path)
        return
    for root, _dirs, files in os.walk(tmp):
        rel = os.path.relpath(root, tmp)
        os.makedirs(os.path.join(path, rel), exist_ok=True)
        for name in files:
            os.replace(os.path.join(root, name), os.path.join(path, rel, name))
    shutil.rmtree(tmp, ignore_errors=True)


# Outputs of one command that must appear together (atomic_group): (final path, publish, discard, temporaries)
_GROUPS: list[list[tuple[str, object, object, tuple[str, ...]]]] = []


def _publish_or_defer(path: str, publish, discard, temps: tuple[str, ...]) -> bool:
    """Publish a finished output now, or at the end of the enclosing :func:`atomic_group` (True then)."""
    if _GROUPS:
        _GROUPS[-1].append((path, publish, discard, temps))
        return True
    publish()
    return False


@contextlib.contextmanager
def atomic_group() -> Iterator[None]:
    """Outputs written by :func:`atomic_path` / :func:`atomic_dir` in the block appear together at its end,
    or none of them: a command with several outputs (labels and a figure, a prediction and its NIfTI
    volumes) that fails on its last one leaves none of the earlier ones behind."""
    _GROUPS.append([])
    try:
        yield
    except BaseException:
        for _path, _publish, discard, _temps in _GROUPS.pop():
            discard()
        raise
    members = _GROUPS.pop()
    for i, (path, publish, _discard, temps) in enumerate(members):
        try:
            publish()
        except BaseException as exc:
            for _p, _pub, discard, _t in members[i:]:
                discard()
            failure = write_failure(exc, path, *temps)
            if failure is not None:
                raise failure from None
            raise


LOCK_SUFFIX = ".lock"


def _pid_in(fd: int) -> str:
    try:
        return os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
    except OSError:
        return "?"


def acquire_output_lock(path: str) -> int | None:
    """Lock ``path`` for this process: ``path.lock`` beside it, holding this process's id, under an
    advisory lock (``flock``) that the system drops when the process ends, however it ends. Returns the
    lock's file descriptor for :func:`release_output_lock` (None for ``-`` or where the platform has no
    ``flock``).

    Raises:
        BusyError: another process holds the lock (one line naming the output, the process and the lock).
    """
    try:
        import fcntl
    except ImportError:          # no advisory locks here: two writers are not told apart
        return None
    if path == "-":
        return None
    lock = path + LOCK_SUFFIX
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise (write_failure(exc, path, lock) or exc) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            other = _pid_in(fd)
            os.close(fd)
            raise BusyError(f"{path}: another less run (process {other}) is writing it (lock {lock}); wait "
                            "for it to end or choose another output") from None
        try:
            same = os.stat(lock).st_ino == os.fstat(fd).st_ino   # not a lock file its last holder removed
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


def release_output_lock(path: str, fd: int | None) -> None:
    """Remove ``path.lock`` and drop the lock taken by :func:`acquire_output_lock` (``fd`` None: nothing)."""
    if fd is None:
        return
    with contextlib.suppress(OSError):
        os.unlink(path + LOCK_SUFFIX)
    os.close(fd)


@contextlib.contextmanager
def output_lock(path: str) -> Iterator[None]:
    """:func:`acquire_output_lock` for the block."""
    fd = acquire_output_lock(path)
    try:
        yield
    finally:
        release_output_lock(path, fd)


def open_input_bytes(path: str) -> io.BytesIO | str:
    """``-`` -> stdin read into memory (seekable, as np.load needs); otherwise the path itself."""
    if path == "-":
        return io.BytesIO(sys.stdin.buffer.read())
    if not os.path.exists(path):
        raise LessError(f"{path}: no such file")
    return path
