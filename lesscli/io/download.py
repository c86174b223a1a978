"""HTTP downloads that resume, verify their checksum and appear atomically (standard library only).

A file is downloaded to ``NAME.part`` beside its destination. An interrupted transfer (the server
closes the connection early, a reset, a timeout) continues from the bytes already there with an HTTP
range request (``Range: bytes=N-``), in the same run (up to ``retries`` times) or in a later one; a
server that ignores the range answers 200 and the transfer starts over. Once the size is reached the
MD5 of the whole file is compared with the published one: a match renames ``NAME.part`` to ``NAME``, a
mismatch deletes it and fails. So ``NAME`` exists only complete and verified.
"""

from __future__ import annotations

import contextlib
import hashlib
import http.client
import json
import os
import re
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass

from lesscli import __version__
from lesscli.errors import LessError

CHUNK_BYTES = 1 << 20
TIMEOUT_S = 60.0
RETRIES = 5
USER_AGENT = f"lesscli/{__version__}"
_CONTENT_RANGE = re.compile(r"bytes (\d+)-\d+/(\d+|\*)")


class DownloadError(LessError):
    """A download failed: dead link, refused connection, wrong size or checksum."""


@dataclass(frozen=True)
class RemoteFile:
    """One published file: its name, where to get it, and what it must be."""

    name: str
    url: str
    size: int | None = None
    md5: str | None = None


def _request(url: str, offset: int = 0) -> urllib.request.Request:
    headers = {"User-Agent": USER_AGENT, "Accept-Encoding": "identity"}
    if offset:
        headers["Range"] = f"bytes={offset}-"
    return urllib.request.Request(url, headers=headers)


def _describe(exc: BaseException) -> str:
    if isinstance(exc, urllib.error.HTTPError):
        return f"HTTP {exc.code} {exc.reason}"
    if isinstance(exc, urllib.error.URLError):
        return f"cannot connect ({exc.reason})"
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def read_json(url: str, timeout_s: float = TIMEOUT_S) -> dict:
    """GET ``url`` and parse its JSON body; DownloadError naming the URL on any failure."""
    try:
        with urllib.request.urlopen(_request(url), timeout=timeout_s) as resp:
            body = resp.read()
    except (urllib.error.URLError, http.client.HTTPException, OSError) as exc:
        raise DownloadError(f"{url}: {_describe(exc)}") from None
    try:
        return json.loads(body)
    except ValueError:
        raise DownloadError(f"{url}: the answer is not JSON") from None


def file_md5(path: str) -> str:
    """Hex MD5 of the file at ``path``."""
    digest = hashlib.md5(usedforsecurity=False)
    with open(path, "rb") as fh:
        while chunk := fh.read(CHUNK_BYTES):
            digest.update(chunk)
    return digest.hexdigest()


class _RunningMd5:
    """MD5 of a growing ``.part`` file, fed as bytes arrive, so a finished download is not read again;
    bytes already on disk (a ``.part`` left by an earlier run) are read once to catch up."""

    def __init__(self) -> None:
        self.digest, self.bytes = hashlib.md5(usedforsecurity=False), 0

    def through(self, part: str, offset: int) -> None:
        """Make the digest cover exactly the first ``offset`` bytes of ``part``."""
        if offset < self.bytes:                      # the file was cut back (a restart): start over
            self.__init__()
        if offset > self.bytes:
            with open(part, "rb") as fh:
                fh.seek(self.bytes)
                while self.bytes < offset and (chunk := fh.read(min(CHUNK_BYTES, offset - self.bytes))):
                    self.update(chunk)

    def update(self, chunk: bytes) -> None:
        self.digest.update(chunk)
        self.bytes += len(chunk)


def _transfer(remote: RemoteFile, part: str, bar, timeout_s: float,
              md5: _RunningMd5) -> tuple[int | None, bool]:
    """One GET from the end of ``part``: append what arrives (and hash it into ``md5``). Returns the total
    size when the server tells it, and whether the bytes continued what ``part`` held (a 206 answer to a
    range from a non-zero offset) rather than starting the file over (200: the whole file re-sent).

    Raises:
        urllib.error.HTTPError: the server answered an error status (416 included).
        OSError, http.client.HTTPException: the connection failed or broke.
    """
    offset = os.path.getsize(part) if os.path.exists(part) else 0
    with urllib.request.urlopen(_request(remote.url, offset), timeout=timeout_s) as resp:
        total = None
        continued = resp.status == 206 and offset > 0
        if resp.status == 206:
            match = _CONTENT_RANGE.match(resp.headers.get("Content-Range", ""))
            if not match or int(match[1]) != offset:
                raise http.client.HTTPException("unexpected Content-Range "
                                                f"{resp.headers.get('Content-Range')!r}")
            total = int(match[2]) if match[2] != "*" else None
        else:                                        # 200: the whole file from the start
            offset = 0
            length = resp.headers.get("Content-Length")
            total = int(length) if length and length.isdigit() else None
        bar.reset(total=total or remote.size)
        bar.update(offset)
        md5.through(part, offset)
        with open(part, "r+b" if offset else "wb") as fh:
            fh.seek(offset)
            fh.truncate()
            while chunk := resp.read(CHUNK_BYTES):
                fh.write(chunk)
                md5.update(chunk)
                bar.update(len(chunk))
    return total, continued


def _verify(remote: RemoteFile, part: str, md5: _RunningMd5, pieces: int) -> str:
    """Size and MD5 of the finished ``part`` (put together from ``pieces`` transfers) against the published
    ones; the hex digest."""
    size = os.path.getsize(part)
    if remote.size is not None and size != remote.size:
        raise DownloadError(f"{remote.url}: got {size} bytes, the record says {remote.size}")
    md5.through(part, size)
    digest = md5.digest.hexdigest()
    if remote.md5 and digest != remote.md5.lower():
        with contextlib.suppress(FileNotFoundError):
            os.remove(part)
        if pieces > 1:       # joined from several transfers: a stale or damaged piece may be the cause
            advice = (f"it was joined from {pieces} transfers, so a fresh one (less fetch again, which now "
                      "starts from zero) may give the published file")
        else:                # one whole transfer: fetching again will most likely give the same bytes
            advice = ("the server sent these bytes in one whole transfer, so fetching again will most likely "
                      "give the same: the file on the server differs from its record (check the record id "
                      "and --base-url, or tell the archive)")
        raise DownloadError(f"{remote.name}: checksum mismatch (md5 {digest}, published {remote.md5}) from "
                            f"{remote.url}; the download was deleted; {advice}")
    return digest


def download(remote: RemoteFile, dest: str, progress: Callable, retries: int = RETRIES,
             timeout_s: float = TIMEOUT_S, backoff_s: float = 1.0) -> dict:
    """Download ``remote`` to ``dest`` (see the module docstring); a record of what was done.

    Args:
        remote: what to get (size and md5 checked when known).
        dest: final path; ``dest + '.part'`` holds an unfinished transfer.
        progress: progress-bar factory (tqdm-like, called with ``total``, ``unit``, ``desc``).
        retries: transfers tried after one that broke off.
        timeout_s: socket timeout of each request.
        backoff_s: pause before a retry, times the retry number.

    Returns:
        ``{"file", "bytes", "md5", "status", "seconds"}``; status ``present`` (already complete and
        verified), ``resumed`` (the file joined from the bytes of several transfers: a ``.part`` of an
        earlier run or try continued with a range request) or ``downloaded`` (in one transfer, also when a
        server that ignores ranges re-sent the whole file).

    Raises:
        DownloadError: dead link (HTTP error), no connection after the retries, wrong size or checksum.
    """
    t0 = time.perf_counter()
    record = {"file": remote.name, "bytes": 0, "md5": None, "status": "downloaded", "seconds": 0.0}
    if os.path.exists(dest) and (remote.size is None or os.path.getsize(dest) == remote.size):
        digest = file_md5(dest)
        if not remote.md5 or digest == remote.md5.lower():
            return {**record, "bytes": os.path.getsize(dest), "md5": digest, "status": "present"}
    part = dest + ".part"
    pieces = 1 if os.path.exists(part) and os.path.getsize(part) > 0 else 0   # a .part of an earlier run
    md5 = _RunningMd5()
    with progress(total=remote.size, unit="B", unit_scale=True, unit_divisor=1024, desc=remote.name) as bar:
        for attempt in range(retries + 1):
            have = os.path.getsize(part) if os.path.exists(part) else 0
            if remote.size is not None and have == remote.size:
                break
            if attempt:
                time.sleep(backoff_s * attempt)
            try:
                total, continued = _transfer(remote, part, bar, timeout_s, md5)
                pieces = pieces + 1 if continued else 1      # a 200 re-sent the whole file: one piece again
            except urllib.error.HTTPError as exc:
                if exc.code == 416 and have:         # the range starts past the end: start over
                    os.remove(part)
                    continue
                raise DownloadError(f"{remote.url}: {_describe(exc)} (dead link?)") from None
            except (OSError, http.client.HTTPException) as exc:
                pieces = max(pieces, 1) if os.path.exists(part) and os.path.getsize(part) else 0
                if attempt == retries:
                    raise DownloadError(f"{remote.url}: transfer failed after {retries + 1} tries "
                                        f"({_describe(exc)}); run again to resume") from None
                continue
            expected = total if total is not None else remote.size
            if expected is None or os.path.getsize(part) >= expected:
                break
        else:
            raise DownloadError(f"{remote.url}: transfer incomplete after {retries + 1} tries "
                                f"({os.path.getsize(part)} bytes); run again to resume")
    digest = _verify(remote, part, md5, pieces)
    os.replace(part, dest)
    return {**record, "bytes": os.path.getsize(dest), "md5": digest,
            "status": "resumed" if pieces > 1 else "downloaded",
            "seconds": round(time.perf_counter() - t0, 3)}
