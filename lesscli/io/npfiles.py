"""Reading ``.npy`` and ``.npz`` files without pickle, each failure one DataError naming the file.

Every reader of the project's array files comes here: a file that is not the kind expected (a folder, an
empty file, a .npy where a .npz belongs, or anything else) is told apart from one that numpy cannot
read (truncated, corrupt, or holding a pickled object, which is refused rather than unpickled).
"""

from __future__ import annotations

import os
import zipfile
import zlib

import numpy as np

from lesscli.errors import DataError
from lesscli.io.atomic import open_input_bytes

NPZ_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")  # a zip archive (with members / empty)
NPY_MAGIC = b"\x93NUMPY"


def _sniff(src, name: str, what: str, npz: bool = True) -> None:
    """Refuse what is not a .npz archive (``npz``) or a .npy array at all, saying what the file is
    instead of numpy's advice to unpickle it."""
    if isinstance(src, str):
        if os.path.isdir(src):
            raise DataError(f"{name}: is a folder, not a {what}")
        with open(src, "rb") as fh:
            head = fh.read(8)
    else:
        head = src.getvalue()[:8]
    check_magic(head, name, what, npz)


def check_magic(head: bytes, name: str, what: str, npz: bool = True) -> None:
    """DataError unless ``head`` (a file's first bytes) opens a .npz archive (``npz``) or a .npy array."""
    if head.startswith(NPZ_MAGIC if npz else (NPY_MAGIC,)):
        return
    if not head:
        raise DataError(f"{name}: not a {what}: the file is empty")
    if head.startswith(NPY_MAGIC):
        raise DataError(f"{name}: not a {what}: it is a single .npy array, expected a .npz archive")
    if head.startswith(NPZ_MAGIC):
        raise DataError(f"{name}: not a {what}: it is a .npz archive, expected a single .npy array")
    raise DataError(f"{name}: not a {what}: not a {'.npz archive' if npz else '.npy array'} "
                    f"(starts with {head[:4]!r})")


def unreadable(name: str, what: str, exc: Exception) -> DataError:
    """The error for a .npy/.npz that numpy cannot read: pickled objects refused, else truncated or
    corrupt."""
    if isinstance(exc, ValueError) and ("allow_pickle" in str(exc) or "Object arrays" in str(exc)):
        return DataError(f"{name}: holds a pickled Python object; a {what} must be a plain array "
                         "(refusing to unpickle)")
    return DataError(f"{name}: not a readable {what} (truncated or corrupt: {exc})")


def read_npy(path: str, what: str) -> np.ndarray:
    """One ``.npy`` array without pickle; a missing, foreign, truncated or pickled file raises DataError."""
    if not os.path.exists(path):
        raise DataError(f"{path}: no such file")
    _sniff(path, path, what, npz=False)
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise unreadable(path, what, exc) from None


def read_npz(path: str, what: str) -> dict[str, np.ndarray]:
    """All arrays of a ``.npz`` without pickle; corrupt, truncated or pickled files raise DataError."""
    name = "<stdin>" if path == "-" else path
    src = open_input_bytes(path)
    _sniff(src, name, what)
    try:
        with np.load(src, allow_pickle=False) as npz:
            arrays = {}
            for key in npz.files:
                try:
                    arrays[key] = npz[key]
                except ValueError as exc:
                    if "allow_pickle" in str(exc) or "Object arrays" in str(exc):
                        raise DataError(f"{name}: key '{key}' holds a pickled Python object; a {what} "
                                        "must hold plain arrays (refusing to unpickle)") from None
                    raise
    except DataError:
        raise
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, KeyError) as exc:
        raise DataError(f"{name}: not a readable .npz {what} (truncated or corrupt: {exc})") from None
    return arrays


ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)     # the earliest time a zip entry can hold: members carry no clock time


def write_npz(path: str, arrays: dict[str, np.ndarray], compress: bool = True) -> None:
    """Write ``arrays`` as a ``.npz`` archive at ``path``, the bytes a function of the arrays alone.

    ``np.savez`` stamps each member with the time of writing, so equal data written twice gave different
    files; here every member carries :data:`ZIP_EPOCH` (as torch's checkpoints do), so a rerun that
    computes the same arrays writes the same bytes. Object arrays are refused (never pickled).
    """
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(path, mode="w", compression=method, allowZip64=True) as archive:
        for key, value in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=ZIP_EPOCH)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            with archive.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
