"""``less bench imaging``: patch stitching and the imaging loss at the paper's grid sizes.

The cases and their baselines are described in :mod:`lesscli.bench.imaging`.
"""

from __future__ import annotations

import click

from lesscli.cli.common import format_option, renamed_option, seed_option, threads_option


@click.command("imaging")
@click.option("--quick", is_flag=True, help="2D only, fewer repeats.")
@renamed_option("--repeat", "--repeats", "repeat", type=click.IntRange(1), default=None,
                help="Timing repeats (best of; default 5, quick 2).")
@renamed_option("--batch", "--batch-size", "batch", type=click.IntRange(1), default=2, show_default=True,
                help="Scans per timed batch.")
@threads_option()
@seed_option()
@format_option()
def cli(quick: bool, repeat: int | None, batch: int, threads: int | None, seed: int, fmt: str | None) -> None:
    """Seconds to stitch 11 x 11 particle patches onto the 128 x 128 (x 26) label grid, vectorised vs a
    per-particle loop, and the Dice-Focal loss vs cross-entropy; then each fast path of the models
    against its plain form over a whole epoch (image fit, prediction)."""
    from lesscli.bench.imaging import run_imaging
    from lesscli.io.records import emit_records
    from lesscli.threads import apply_threads

    apply_threads("throughput", override=threads)
    emit_records(run_imaging((2,) if quick else (2, 3), batch, repeat or (2 if quick else 5), seed,
                             batches=2 if quick else 4), fmt)
