"""Where the published dataset is read from: a folder, or a zip archive read in place (no extraction).

Both sources name files by their path relative to the dataset root, with ``/`` separators. The root
of a folder is the folder; the root of a zip is its single top folder when every member sits in one
(the published archives wrap one folder each), else the archive's top level. So importing
``dataset_poke.zip`` and importing the folder that unzipping it gives (``unzipped/dataset_poke``)
read the same files under the same names.

Zip members are opened without writing anything to disk. HDF5 reads seek back and forth, which a
``zipfile`` member stream can only do by re-reading (and re-inflating) from the start of the member:
measured on a 20 MB scan file that is 40 times slower stored and 300 times slower deflated than the
plain file. So a stored member is read through :class:`MemberView`, a seekable window onto the
member's bytes inside the archive (as fast as the extracted file), and a deflated member is inflated
once into memory (about half the speed of the plain file; memory use is one scan file at a time).
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
import zipfile

import numpy as np

from lesscli.errors import DataError

LOCAL_HEADER_BYTES = 30                 # fixed part of a zip local file header
LOCAL_HEADER_MAGIC = b"PK\x03\x04"


class MemberView(io.RawIOBase):
    """A read-only, seekable file over ``length`` bytes starting at ``start`` of an open binary file."""

    def __init__(self, fh, start: int, length: int) -> None:
        super().__init__()
        self._fh, self._start, self._length, self._pos = fh, start, length, 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._pos

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._pos, io.SEEK_END: self._length}[whence]
        if base + offset < 0:
            raise ValueError(f"negative seek position {base + offset}")
        self._pos = base + offset
        return self._pos

    def readinto(self, buffer) -> int:
        n = max(0, min(len(buffer), self._length - self._pos))
        self._fh.seek(self._start + self._pos)
        got = self._fh.readinto(memoryview(buffer)[:n])
        self._pos += got
        return got


class FolderSource:
    """The dataset as a folder on disk."""

    def __init__(self, root: str) -> None:
        if not os.path.isdir(root):
            raise DataError(f"{root}: not a directory or zip archive (expected the root of the published "
                            "dataset)")
        self.root = root
        self._files: list[str] | None = None

    def where(self, rel: str) -> str:
        """The name of ``rel`` in messages."""
        return os.path.join(self.root, rel)

    def files(self) -> list[str]:
        """Every file under the root, relative, sorted (listed once)."""
        if self._files is None:
            found = []
            for folder, _dirs, names in os.walk(self.root):
                found += [os.path.relpath(os.path.join(folder, n), self.root).replace(os.sep, "/")
                          for n in names]
            self._files = sorted(found)
        return self._files

    def is_file(self, rel: str) -> bool:
        return os.path.isfile(self.where(rel))

    def open(self, rel: str):
        """A context giving what h5py.File and np.load open: here the file's path (HDF5's own driver)."""
        return contextlib.nullcontext(self.where(rel))

    def close(self) -> None:
        pass


class ZipSource:
    """The dataset as a zip archive, read in place."""

    def __init__(self, path: str) -> None:
        try:
            self.zip = zipfile.ZipFile(path)
            self._fh = open(path, "rb")  # noqa: SIM115 (closed by close(); held for the life of the source)
        except (OSError, zipfile.BadZipFile) as exc:
            raise DataError(f"{path}: not a readable zip archive ({exc})") from None
        self.path = path
        self._members = {i.filename: i for i in self.zip.infolist() if not i.is_dir()}
        tops = {name.split("/", 1)[0] for name in self._members}
        nested = all("/" in name for name in self._members)
        self.prefix = f"{tops.pop()}/" if len(tops) == 1 and nested else ""

    def where(self, rel: str) -> str:
        return f"{self.path}:{self.prefix}{rel}"

    def files(self) -> list[str]:
        return sorted(n[len(self.prefix):] for n in self._members)

    def is_file(self, rel: str) -> bool:
        return self.prefix + rel in self._members

    def open(self, rel: str):
        """A seekable binary file object over one member (see the module docstring); a context too."""
        info = self._members[self.prefix + rel]
        if info.flag_bits & 0x1:
            raise DataError(f"{self.where(rel)}: encrypted zip members are not supported")
        if info.compress_type != zipfile.ZIP_STORED:
            return io.BytesIO(self.zip.read(info))
        self._fh.seek(info.header_offset)
        header = self._fh.read(LOCAL_HEADER_BYTES)
        if len(header) != LOCAL_HEADER_BYTES or header[:4] != LOCAL_HEADER_MAGIC:
            raise DataError(f"{self.where(rel)}: damaged zip archive (no local header at "
                            f"{info.header_offset})")
        name_len, extra_len = struct.unpack("<HH", header[26:30])
        start = info.header_offset + LOCAL_HEADER_BYTES + name_len + extra_len
        return io.BufferedReader(MemberView(self._fh, start, info.file_size), buffer_size=1 << 16)

    def close(self) -> None:
        self.zip.close()
        self._fh.close()


def open_source(path: str) -> FolderSource | ZipSource:
    """A zip archive (by content, any extension) or a folder."""
    if os.path.isfile(path) and zipfile.is_zipfile(path):
        return ZipSource(path)
    return FolderSource(path)


def load_array(source: FolderSource | ZipSource, rel: str, what: str) -> np.ndarray | dict:
    """A ``.npy`` array or the arrays of a ``.npz`` (by ``rel``'s extension) from ``source``, without
    pickle; DataError naming the file."""
    from lesscli.io.npfiles import check_magic, unreadable

    where = source.where(rel)
    try:
        with source.open(rel) as fh:
            if isinstance(fh, str):                                 # a folder's file: its path
                with open(fh, "rb") as raw:
                    head = raw.read(8)
            else:
                head = fh.read(8)
                fh.seek(0)
            check_magic(head, where, what, npz=rel.lower().endswith(".npz"))
            loaded = np.load(fh, allow_pickle=False)
            if isinstance(loaded, np.lib.npyio.NpzFile):
                with loaded:
                    return {k: loaded[k] for k in loaded.files}
            return loaded
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise unreadable(where, what, exc) from None
