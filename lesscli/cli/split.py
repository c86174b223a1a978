"""``less split FILE --by insert|scan --test F [--val F] --seed S -o DIR``."""

from __future__ import annotations

import click

from lesscli.cli.common import format_option, output_option, seed_option


@click.command("split")
@click.argument("path", type=click.Path(), metavar="FILE")
@click.option("--by", type=click.Choice(["insert", "scan"]), default="insert", show_default=True,
              help="Unit kept whole: 'insert' (no insert in two splits) or 'scan'.")
@click.option("--test", type=click.FloatRange(0, 1, max_open=True), default=0.2, show_default=True,
              help="Share of inserts (or scans) for test.")
@click.option("--val", type=click.FloatRange(0, 1, max_open=True), default=0.0, show_default=True,
              help="Share for validation (0: no val.npz).")
@seed_option()
@output_option(help="Output folder (train.npz, val.npz, test.npz).", folder=True)
@format_option()
def cli(path: str, by: str, test: float, val: float, seed: int, output: str, fmt: str | None) -> None:
    """Split a scan set into DIR/train.npz, DIR/val.npz (with --val) and DIR/test.npz.

    Prints one record per split (scans, trajectories, steps, inserts).

    Example: less split poke.npz --by insert --test 0.2 --val 0.1 --seed 0 -o split/
    """
    import os

    import numpy as np

    from lesscli.data.ops import split, split_record
    from lesscli.io.atomic import atomic_dir
    from lesscli.io.records import emit_records
    from lesscli.io.scans import append_history, load_scans, save_scans

    if test + val >= 1:
        raise click.UsageError("--test plus --val must be below 1")
    scans = load_scans(path)
    parts = split(scans, by, test, val, np.random.default_rng(seed), name=path)
    rows = []
    with atomic_dir(output) as tmp:
        for name, part in parts.items():
            part.meta = append_history(part.meta, seed=seed, split=name)
            save_scans(os.path.join(tmp, f"{name}.npz"), part)
            rows.append(split_record(name, part, os.path.join(output, f"{name}.npz")))
    emit_records(rows, fmt)
