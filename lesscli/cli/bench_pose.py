"""``less bench pose``: sensor-pose error and time per frame of the tracking variants on rendered frames.

The rendered set, the variants and the baseline are described in :mod:`lesscli.bench.pose`.
"""

from __future__ import annotations

import click

from lesscli.cli.common import format_option, seed_option


@click.command("pose")
@click.option("--quick", is_flag=True, help="8 frames instead of 60.")
@click.option("--frames", "n_frames", type=int, default=None, help="Frames to render (overrides --quick).")
@format_option()
@seed_option()
def cli(quick: bool, n_frames: int | None, fmt: str | None, seed: int) -> None:
    """Pose error and time per frame of the tracking variants against the plain AprilTag pipeline.

    Example: less bench pose --quick --format table
    """
    from lesscli.bench.pose import run_pose
    from lesscli.io.records import emit_records

    emit_records(run_pose(n_frames or (8 if quick else 60), seed), fmt)
