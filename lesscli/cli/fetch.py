"""``less fetch RECORD... -o DIR``: download published records, resumable and checksum-verified."""

from __future__ import annotations

import click

from lesscli.cli.common import LOG, format_option
from lesscli.data.archive import DEFAULT_BASE_URL


@click.command("fetch")
@click.argument("records", nargs=-1, required=True, metavar="RECORD...")
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False), metavar="DIR",
              help="Folder for the downloaded files (created if missing).")
@click.option("--base-url", default=DEFAULT_BASE_URL, show_default=True, metavar="URL",
              help="The archive to ask (its /api/records/<id> describes a record).")
@click.option("--file", "only", multiple=True, metavar="NAME",
              help="Fetch only this file of the records (repeatable; default: every file).")
@click.option("--retries", type=click.IntRange(min=0), default=5, show_default=True,
              help="Transfers tried again (resuming) after one breaks off.")
@format_option()
def cli(records: tuple[str, ...], out_dir: str, base_url: str, only: tuple[str, ...], retries: int,
        fmt: str | None) -> None:
    """Download the files of published records into DIR.

    RECORD is a record id or one of the names poke (20367204), primitive (20367198) and
    generalisation (20367501: big, multi and hand-held sets). Each file is downloaded to NAME.part
    with HTTP range requests, so a broken transfer resumes (in this run, or the next one), then its
    MD5 is checked against the published checksum and NAME appears only when it matches; a complete
    NAME is verified and kept. One record per file goes to stdout, a byte progress bar to stderr.

    Example: less fetch poke primitive -o data/ && less import data/dataset_poke.zip -o poke.npz
    """
    import os

    from lesscli.cli.common import progress
    from lesscli.data.archive import record_files, record_id, record_url
    from lesscli.errors import LessError
    from lesscli.io.download import download, read_json
    from lesscli.io.records import emit_records

    listed = []
    for name in records:
        rid = record_id(name)
        listed += [(rid, f) for f in record_files(read_json(record_url(base_url, rid)), base_url, rid)]
    missing = set(only) - {f.name for _rid, f in listed}
    if missing:
        raise LessError(f"{', '.join(sorted(missing))}: not a file of record(s) {', '.join(records)}")
    os.makedirs(out_dir, exist_ok=True)

    def fetched():
        for rid, remote in listed:
            if not only or remote.name in only:
                if remote.md5 is None:
                    LOG.warning("%s: record %s publishes no checksum; only the size is checked", remote.name,
                                rid)
                row = download(remote, os.path.join(out_dir, remote.name), progress, retries=retries)
                LOG.info("%s: %s (%d bytes)", remote.name, row["status"], row["bytes"])
                yield {"record": rid, **row}

    emit_records(fetched(), fmt)
