"""The published records in the public research-data archive, and their files (``less fetch``).

A record is described as JSON at ``<base>/api/records/<id>``; its ``files`` list has one entry per
file with ``key`` (the name), ``size`` (bytes), ``checksum`` (``"md5:<hex>"``) and ``links`` (the
download link under ``content``, ``download`` or ``self``). The older shape of the same API
(``filename``, ``filesize``, a bare hex checksum) and a ``files`` object with ``entries`` are read
too. A file without a link is fetched from ``<base>/api/records/<id>/files/<key>/content``.
"""

from __future__ import annotations

import urllib.parse

from lesscli.errors import DataError, LessError
from lesscli.io.download import RemoteFile

DEFAULT_BASE_URL = "https://zenodo.org"
RECORDS = {
    "poke": "20367204",             # dataset_poke.zip
    "primitive": "20367198",        # dataset_primitive.zip
    "generalisation": "20367501",   # dataset_poke_big.zip, dataset_poke_multi.zip, dataset_handheld.zip
}
LINK_KEYS = ("content", "download", "self")


def record_id(name: str) -> str:
    """A record id (digits) or one of the names in RECORDS -> the id."""
    if name.isdigit():
        return name
    if name in RECORDS:
        return RECORDS[name]
    raise LessError(f"record '{name}': neither a record id (digits) nor one of {', '.join(RECORDS)}")


def record_url(base_url: str, rid: str) -> str:
    """The JSON description of record ``rid``."""
    return f"{base_url.rstrip('/')}/api/records/{rid}"


def _entries(description: dict, where: str) -> list[dict]:
    files = description.get("files") if isinstance(description, dict) else None
    if isinstance(files, dict):
        files = files.get("entries")
        files = list(files.values()) if isinstance(files, dict) else files
    if not isinstance(files, list) or not all(isinstance(f, dict) for f in files):
        raise DataError(f"{where}: the record description has no 'files' list")
    return files


def _md5(checksum, where: str) -> str | None:
    if checksum is None:
        return None
    algo, _, value = str(checksum).rpartition(":")
    if algo not in ("", "md5") or len(value) != 32:
        raise DataError(f"{where}: checksum '{checksum}' is not md5:<32 hex digits>")
    return value.lower()


def record_files(description: dict, base_url: str, rid: str) -> list[RemoteFile]:
    """The files of a record from its JSON description (see the module docstring)."""
    where = record_url(base_url, rid)
    out = []
    for entry in _entries(description, where):
        name = entry.get("key") or entry.get("filename")
        if not isinstance(name, str) or not name or "/" in name or "\\" in name or name in (".", ".."):
            raise DataError(f"{where}: file entry with an unusable name {name!r}")
        links = entry.get("links") if isinstance(entry.get("links"), dict) else {}
        link = next((links[k] for k in LINK_KEYS if isinstance(links.get(k), str)), None)
        url = urllib.parse.urljoin(where, link) if link else \
            f"{where}/files/{urllib.parse.quote(name)}/content"
        size = entry.get("size", entry.get("filesize"))
        out.append(RemoteFile(name, url, int(size) if size is not None else None,
                              _md5(entry.get("checksum"), f"{where}: {name}")))
    if not out:
        raise DataError(f"{where}: the record lists no files")
    return out
