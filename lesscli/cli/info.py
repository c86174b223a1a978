"""``less info FILE``: what a scan set holds."""

from __future__ import annotations

import click

from lesscli.cli.common import format_option


@click.command("info")
@click.argument("path", type=click.Path(), metavar="FILE")
@click.option("--full-history", is_flag=True,
              help="Show history entries as stored (time, output file) instead of the summary.")
@format_option
def cli(path: str, full_history: bool, fmt: str | None) -> None:
    """Describe a scan set: counts, shapes, units, sensor, label geometry, history.

    FILE is a .npz scan set, a directory of shards, or '-' for stdin.

    The history summary leaves out output paths and times, so the same data read from a file or
    from a pipe gives the same record.

    Example: less info scans.npz --format table
    """
    from lesscli.data.describe import describe
    from lesscli.io.records import emit_records
    from lesscli.io.scans import load_scans

    emit_records(describe(load_scans(path), path, full_history=full_history), fmt)
