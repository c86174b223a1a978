"""``less info FILE``: what a scan set, prediction file, checkpoint, label volume or MRI scan holds."""

from __future__ import annotations

import click

from lesscli.cli.common import format_option, series_option


@click.command("info")
@click.argument("paths", type=click.Path(), metavar="FILE...", nargs=-1, required=True)
@click.option("--full-history", is_flag=True,
              help="Show history entries as stored (time, output file) instead of the summary.")
@series_option()
@format_option()
def cli(paths: tuple[str, ...], full_history: bool, series: str | None, fmt: str | None) -> None:
    """Describe a file: a scan set (counts, shapes, units, sensor, label geometry, history), a
    prediction file (scans, grids, model, labelled voxels, entropy), a checkpoint (model, parameters,
    epochs, best loss, image grid), a label volume (grid, voxels and mm^3 per class) or an MRI scan
    (grid and intensities).

    FILE is a .npz scan set or prediction file, a folder of scan-set shards, '-' for either on stdin,
    a .pt checkpoint, a .nii/.nii.gz label volume or MRI scan, or a DICOM folder.

    The history summary leaves out output paths and times, so the same data read from a file or
    from a pipe gives the same record. Several files: each record names its file, and a table is
    written per file; every file is read before anything is written.

    Examples:

      less info scans.npz --format table

      less info demo-out/*.pt demo-out/*.npz
    """
    import sys

    from lesscli.data.describe import describe_file
    from lesscli.io.records import emit_records, resolve_format

    records = [describe_file(path, full_history=full_history, series=series) for path in paths]
    if len(paths) > 1:
        records = [[{"file": path, **row} for row in rows] for path, rows in zip(paths, records)]
    fmt = resolve_format(fmt)
    if fmt in ("table", "markdown"):
        for i, rows in enumerate(records):
            if i:
                sys.stdout.write("\n")
            emit_records(rows, fmt)
    else:
        emit_records([row for rows in records for row in rows], fmt)
