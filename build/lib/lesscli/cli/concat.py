"""``less concat A B ... -o OUT``: one scan set from several."""

from __future__ import annotations

import click

from lesscli.cli.common import LOG, output_option


@click.command("concat")
@click.argument("paths", type=click.Path(), metavar="FILE...", nargs=-1, required=True)
@output_option()
def cli(paths: tuple[str, ...], output: str) -> None:
    """Concatenate scan sets whose sensor and units agree; identical label volumes are stored once.

    Each FILE is a .npz scan set or a folder of shards ('-' once for stdin).

    Example: less concat poke.npz primitives.npz -o all.npz
    """
    from lesscli.errors import DataError
    from lesscli.io.scans import append_history, concat, load_scans, save_scans

    if list(paths).count("-") > 1:
        raise DataError("'-' (stdin) can be given only once")
    out = concat([load_scans(p) for p in paths], names=list(paths))
    out.meta = append_history(out.meta)
    save_scans(output, out)
    LOG.info("%s: %d scans, %d label volumes", output, out.n_scans, len(out.labels))
