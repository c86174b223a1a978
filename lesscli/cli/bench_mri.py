"""``less bench mri``: seconds to label a synthetic MRI volume (256^3 by default) on one core.

The baseline and the columns are described in :mod:`lesscli.bench.mri`.
"""

from __future__ import annotations

import click

from lesscli.bench.mri import FULL_SIZE, KNOBS, QUICK_SIZE, one_core, run_knobs, run_mri
from lesscli.cli.common import checked_output, format_option, seed_option

KNOB_COLUMNS = ["knob", "value", "seconds", "ratio_vs_default", "dice_insert", "dice_pillar",
                "dice_inclusion", "dice_pillar_delta", "dice_inclusion_delta", "warnings"]


@click.command("mri")
@click.option("--quick", is_flag=True, help=f"A {QUICK_SIZE}^3 volume instead of {FULL_SIZE}^3.")
@click.option("--size", type=click.IntRange(min=48), default=None, help="Voxels per axis (cubic volume).")
@click.option("--insert", "insert_name", default="St12C13", show_default=True,
              help="Catalogue insert to synthesise.")
@click.option("--contrast", type=click.Choice(["silicone-darker", "silicone-brighter"]),
              default="silicone-darker", show_default=True,
              help="Which tissue is brighter in the synthetic scan.")
@click.option("--knobs", is_flag=True,
              help=f"Instead: label the volume once per setting of each knob ({', '.join(KNOBS)}), one "
                   "changed at a time, seconds against the defaults' and Dice per class.")
@click.option("--plot", "plot_path", type=click.Path(), default=None, callback=checked_output(),
              help="With --knobs: PNG of pillar and inclusion Dice against seconds (Pareto).")
@seed_option()
@format_option()
def cli(quick: bool, size: int | None, insert_name: str, contrast: str, knobs: bool, plot_path: str | None,
        seed: int, fmt: str | None) -> None:
    """Time to label one cubic MRI volume (all steps, one core) against plain thresholding; with --knobs,
    what each of mri-label's knobs trades in Dice for time."""
    if plot_path and not knobs:
        raise click.UsageError("--plot needs --knobs")
    one_core()
    from lesscli.io.records import emit_records

    n = size or (QUICK_SIZE if quick else FULL_SIZE)
    if not knobs:
        emit_records(run_mri(n, insert_name, contrast, seed), fmt)
        return
    rows = run_knobs(n, insert_name, contrast, seed)
    if plot_path:
        from lesscli.plots.sweeps import pareto_figure

        pareto_figure(rows, plot_path, time_key="seconds", scores=("dice_pillar", "dice_inclusion"),
                      title=f"less mri-label on a {n}^3 volume: Dice against seconds (one knob at a time)")
    emit_records(rows, fmt, columns=KNOB_COLUMNS)
