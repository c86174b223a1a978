"""``less info FILE``: what a scan set holds."""

from __future__ import annotations

import click

from lesscli.cli.common import format_option


@click.command("info")
@click.argument("path", metavar="FILE")
@format_option
def cli(path: str, fmt: str | None) -> None:
    """Describe a scan set: counts, shapes, units, sensor, label geometry, history.

    FILE is a .npz scan set, a directory of shards, or '-' for stdin.

    Example: less info scans.npz --format table
    """
    from lesscli.data.describe import describe
    from lesscli.io.records import emit_records
    from lesscli.io.scans import load_scans

    emit_records(describe(load_scans(path), path), fmt)
