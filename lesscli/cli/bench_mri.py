"""``less bench mri``: seconds to label a synthetic MRI volume (256^3 by default) on one core.

The baseline and the columns are described in :mod:`lesscli.bench.mri`.
"""

from __future__ import annotations

import click

from lesscli.bench.mri import FULL_SIZE, QUICK_SIZE, one_core, run_mri
from lesscli.cli.common import format_option, seed_option


@click.command("mri")
@click.option("--quick", is_flag=True, help=f"A {QUICK_SIZE}^3 volume instead of {FULL_SIZE}^3.")
@click.option("--size", type=click.IntRange(min=48), default=None, help="Voxels per axis (cubic volume).")
@click.option("--insert", "insert_name", default="St12C13", show_default=True, help="Catalogue insert to synthesise.")
@click.option("--contrast", type=click.Choice(["silicone-darker", "silicone-brighter"]), default="silicone-darker",
              show_default=True, help="Which tissue is brighter in the synthetic scan.")
@seed_option()
@format_option
def cli(quick: bool, size: int | None, insert_name: str, contrast: str, seed: int, fmt: str | None) -> None:
    """Time to label one cubic MRI volume (all steps, one core) against plain thresholding."""
    one_core()
    from lesscli.io.records import emit_records

    emit_records(run_mri(size or (QUICK_SIZE if quick else FULL_SIZE), insert_name, contrast, seed), fmt)
