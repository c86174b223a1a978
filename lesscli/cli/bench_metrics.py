"""``less bench metrics``: time to score one 26x128x128 volume with a 16 mm inclusion.

The cases and their baselines are described in :mod:`lesscli.bench.metrics`.
"""

from __future__ import annotations

import click

from lesscli.cli.common import format_option, renamed_option, seed_option


@click.command("metrics")
@click.option("--quick", is_flag=True, help="Fewer repeats.")
@renamed_option("--repeat", "--repeats", "repeat", type=click.IntRange(1), default=None,
                help="Timing repeats (best of; default 7, quick 2).")
@click.option("--diameter-mm", type=click.FloatRange(min=1.0, max=25.0), default=16.0, show_default=True,
              help="Diameter of the synthetic inclusion.")
@seed_option()
@format_option()
def cli(quick: bool, repeat: int | None, diameter_mm: float, seed: int, fmt: str | None) -> None:
    """Seconds to score one volume (all 3D + 2D metrics) against the F1-only and all-pairs baselines."""
    from lesscli.bench.metrics import run_metrics
    from lesscli.io.records import emit_records

    emit_records(run_metrics(diameter_mm, repeat or (2 if quick else 7), seed), fmt)
